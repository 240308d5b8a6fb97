"""Batched lockstep: B trials advanced together as one vectorised system give the numbers of B single runs.

Measured (tiny ConvDecoder at 32x32, 3 trials, 60 steps, torch on 1 thread): the event times,
ball and gamma are bitwise equal; the float results differ in the last bits only (batched
conv and linear kernels round differently per batch size): max relative difference about
2e-9 on mu and 2e-7 on the float32 visual error. The test asserts 1e-6.
"""
import functools

import numpy as np
import pytest
import torch

from rhi.components.body import kinematics
from rhi.components.vision.component import Decoder, GenerativeModel
from rhi.components.vision.networks import build
from rhi.master import config as configuration
from rhi.master.tasks import illusion as experiment
from rhi.master.decoders.training_data import HALF_RANGES

STEPS = 60
FLOAT32_SUM = 32 * 32 * 2.0 ** -24  # worst relative error of a float32 sum of the 32^2 pixels' terms


def tiny_model(seed=0) -> GenerativeModel:
    """An untrained tiny ConvDecoder at 32x32, seeded (speed and batching do not depend on the weights)."""
    torch.manual_seed(seed)
    return GenerativeModel(build("conv", "tiny", 32).decoder, kinematics.REST_POSE, HALF_RANGES)


def tiny_config(steps=STEPS):
    """32x32, a touch every 0.4 s (so both stimulations give events in 60 steps), a strong visual drive
    (Sigma_v = 1e-4 makes the untrained decoder move mu by 0.3-1.2 deg in 60 steps)."""
    return configuration.load(overrides={"experiment.resolution": 32, "experiment.steps": steps,
                                         "decoder.visual_variance": 1e-4, "stimulus.period": 0.4})


def three_trials(config):
    """Three trials that differ in condition, stimulation and seed."""
    trials = experiment.plan(config)
    chosen = [t for t in trials if (t.decoder, t.condition, t.stimulation, t.index) in
              {("conv", "left", "sync", 0), ("conv", "center", "async", 1), ("conv", "right", "async", 2)}]
    assert len(chosen) == 3
    return chosen


@functools.lru_cache(maxsize=None)
def reference_runs():
    """The three trials batched and one by one, computed once per session (test_fast and test_bench reuse them)."""
    model, config = tiny_model(), tiny_config()
    trials = three_trials(config)
    batched = experiment.run_batch(Decoder(model, threads=1), trials, config)
    singles = [experiment.run_batch(Decoder(model, threads=1), [trial], config) for trial in trials]
    return trials, batched, singles


@pytest.fixture(scope="module")
def runs():
    return reference_runs()


def test_batched_equals_single_runs_for_every_recorded_output(runs):
    trials, batched, singles = runs
    assert batched.batch_size == 3 and set(batched.values) == set(experiment.RECORD)
    for path in experiment.RECORD:
        together = batched.values[path]
        one_by_one = np.concatenate([single.values[path] for single in singles], axis=1)
        assert together.shape == one_by_one.shape == (STEPS + 1, 3, *together.shape[2:])
        if path in ("stimulus.visual_time", "stimulus.tactile_time", "stimulus.ball", "brain.gamma"):
            assert np.array_equal(together, one_by_one), path  # no float kernel in between: bitwise
        else:  # batching reorders the decoder's float32 sums over its 32^2 pixels: N u = 6e-5 of each drive,
            # over the <= 1.2 deg mu moves <= 7e-5 deg, within rtol 1e-6 of mu (~150 deg); atol 1e-6 (16 u) for
            # the outputs near 0 and the images (<= 1); the visual error within 6e-5 of itself (N u)
            rtol = FLOAT32_SUM if path == "decoder.visual_error" else 1e-6
            np.testing.assert_allclose(together, one_by_one, rtol=rtol, atol=1e-6, err_msg=path)


def test_the_trials_really_differ_and_move(runs):
    """Guards the test above against passing vacuously: distinct stimuli, events, moving beliefs."""
    trials, batched, _ = runs
    values = batched.values
    assert len({(t.condition, t.stimulation, t.seed) for t in trials}) == 3
    assert np.isfinite(values["stimulus.tactile_time"][-1]).all()  # every trial had touches
    assert len(np.unique(values["stimulus.tactile_time"][-1])) == 3  # at different times
    moved = np.abs(values["brain.mu"][-1] - values["brain.mu"][0]).max(axis=1)
    assert (moved > 0.1).all() and len(np.unique(np.round(moved, 6))) == 3
    offsets = np.array([t.offset_x for t in trials])
    assert np.allclose(values["stimulus.ball"][-1, :, 0] - kinematics.REST_HAND[0], offsets)  # ball at each rubber hand


def test_batch_order_does_not_matter(runs):
    trials, batched, _ = runs
    config = tiny_config()
    reversed_run = experiment.run_batch(Decoder(tiny_model(), threads=1), trials[::-1], config)
    for path in ("brain.mu", "body.force_x", "decoder.visual_error"):  # tolerances as in the test above
        rtol = FLOAT32_SUM if path == "decoder.visual_error" else 1e-6
        np.testing.assert_allclose(reversed_run.values[path][:, ::-1], batched.values[path], rtol=rtol, atol=1e-6)
