"""Readings and the rubber arm's visibility over time, against hand computation: the blocks a reading cuts, the
visibility signal, a reading that hides the arm (the seen image is the scene without it), a 7-minute design read
every 10 s (42 blocks), and the refusals, one line each."""
import math

import numpy as np
import pytest
from test_stimulus import run_stimulus

from rhi.components.body import kinematics
from rhi.components.body.camera import ball_alpha, composite
from rhi.components.stimulus import block_rows, interval_rows
from rhi.components.vision.component import Decoder, GenerativeModel
from rhi.components.vision.networks import build
from rhi.master import config as configuration
from rhi.master.config import protocol
from rhi.master.config.schedules import hidden_intervals, stroking_blocks
from rhi.master.cosim import simulate
from rhi.master.tasks.illusion import wiring

INF = math.inf


def readings(times, duration, hide=False):
    return {"times": times, "duration": duration, "hide_arm": hide}


def test_readings_cut_the_blocks_by_hand():
    # one block over the trial, readings of 3 s at 10 and 20 s: [0, 10], [13, 20], [23, inf]
    assert stroking_blocks([], readings([10.0, 20.0], 3.0)) == ((0.0, 10.0), (13.0, 20.0), (23.0, INF))
    # a reading across a block's end and one inside the next: [0, 8]; [12, 15], [17, 30]
    assert stroking_blocks([[0, 9], [11, 30]], readings([8.0, 15.0], 2.0)) == ((0.0, 8.0), (11.0, 15.0), (17.0, 30.0))
    # a reading between blocks leaves them; no reading, or readings of no duration, leave the schedule as it is
    assert stroking_blocks([[0, 5], [10, 20]], readings([6.0], 3.0)) == ((0.0, 5.0), (10.0, 20.0))
    assert stroking_blocks([], readings([], 3.0)) == () and stroking_blocks([], readings([10.0], 0.0)) == ()


def test_hidden_intervals_merge_the_hidden_times_and_the_hiding_readings():
    config = {"rubber_arm": {"hidden_times": [[0.0, 5.0], [30.0, 40.0]]}, "readings": readings([4.0, 50.0], 2.0, True)}
    assert hidden_intervals(config) == ((0.0, 6.0), (30.0, 40.0), (50.0, 52.0))
    config["readings"]["hide_arm"] = False
    assert hidden_intervals(config) == ((0.0, 5.0), (30.0, 40.0))


def test_the_stimulus_pauses_in_a_reading_and_signals_the_arm_out_of_view():
    # period 1 s, readings at 3 s and 6 s lasting 1.5 s: blocks [0, 3], [4.5, 6], [7.5, inf], touches at start + k
    # period within each: 1, 2, 3 | 5.5 (6.5 is past the block) | 8.5, 9.5
    blocks = stroking_blocks([], readings([3.0, 6.0], 1.5))
    hidden = hidden_intervals({"rubber_arm": {"hidden_times": []}, "readings": readings([3.0, 6.0], 1.5, True)})
    out = run_stimulus(10.0, 2, period=1.0, delay_max=0.0, blocks=np.stack([block_rows(blocks)] * 2),
                       hidden=np.stack([interval_rows(hidden)] * 2), arm_in_view=[True, False])
    visual = out["visual_time"][:, 0]
    fresh = np.isfinite(visual[1:]) & (visual[1:] != visual[:-1])
    assert visual[1:][fresh].tolist() == [1.0, 2.0, 3.0, 5.5, 8.5, 9.5]
    time = np.arange(len(visual)) * 0.02
    # visible outside [3, 4.5) and [6, 7.5), each read at the step's end; never in the trial without a rubber arm
    expected = np.where(((time >= 3.0 - 1e-9) & (time < 4.5 - 1e-9)) | ((time >= 6.0 - 1e-9) & (time < 7.5 - 1e-9)),
                        0.0, 1.0)
    assert np.array_equal(out["arm_visible"][:, 0], expected)
    assert np.all(out["arm_visible"][:, 1] == 0.0)


def tiny_decoder():
    return Decoder(GenerativeModel(build("conv", "tiny", 16).decoder, kinematics.REST_POSE, (40.0, 50.0),
                                   {"kind": "conv"}), threads=1)


def test_a_reading_that_hides_the_arm_leaves_the_ball_alone_in_the_seen_image():
    config = configuration.load(overrides={"experiment.resolution": 16, "experiment.steps": 100,
                                           "experiment.decoders": ["conv"], "readings.times": [0.5],
                                           "readings.duration": 1.0, "readings.hide_arm": True})
    trials = [protocol.make_trial(config, "conv", "right", "sync", 0)]
    system = wiring.build_system(tiny_decoder(), config, trials=trials)
    given = wiring.screen_parameters(wiring.parameters(trials, config), system)
    given = {path: value for path, value in given.items() if path.partition(".")[0] in system.components}
    result = simulate(system, stop_time=2.0, step_size=0.02, parameters=given,
                      record=["screen.seen", "camera.image", "stimulus.ball", "stimulus.arm_visible"])
    seen, full, balls = (result.values[p][:, 0] for p in ("screen.seen", "camera.image", "stimulus.ball"))
    time = result.times
    during = (time >= 0.5 - 1e-9) & (time < 1.5 - 1e-9)
    assert during.sum() == 50 and np.array_equal(result.values["stimulus.arm_visible"][:, 0], (~during) * 1.0)
    for k in np.flatnonzero(during):  # the scene without the arm: the ball's disc over black, drawn here
        alone = composite(np.zeros((16, 16), np.float32), ball_alpha(balls[k], 16))
        assert np.array_equal(seen[k], alone)
        assert full[k].sum() > seen[k].sum() + 1.0  # the camera saw the arm then (its pixels, at least one in all)
    assert np.array_equal(seen[~during], full[~during])  # otherwise the camera's image as it is
    plain = wiring.build_system(tiny_decoder(), configuration.load()).components
    assert "screen" not in plain and "ball_camera" not in plain  # no screen unless the arm is hidden for a while


@pytest.fixture(scope="module")
def tiny_ownership(tmp_path_factory):
    """The ownership model at 16 px with an untrained tiny pose encoder."""
    from rhi.components.vision import pose_encoder as pe
    from rhi.components.vision.networks import Encoder, preset

    path = tmp_path_factory.mktemp("pose") / "pose.pt"
    pe.save_encoder(path, pe.PoseModel(Encoder(preset("tiny"), 16), (147.7, -91.2), (40.0, 50.0), (1.0, 1.0)),
                    preset("tiny"), 16)
    return {"experiment.resolution": 16, "experiment.trials": 1, "ownership.conv_pose_encoder": str(path),
            "ownership.vae_pose_encoder": str(path)}


def test_a_seven_minute_design_read_every_ten_seconds_runs_its_42_blocks(tiny_ownership):
    # 420 s at 0.1 s steps (the step does not change the schedule; the plant needs sub-steps under 2.7 ms: 40 a
    # step), readings of 3 s at 10, 20, ..., 410 s
    config = configuration.load(overrides={**tiny_ownership, "experiment.steps": 4200, "experiment.step_size": 0.1,
                                           "body.substeps": 40, "readings.times": [10.0 * k for k in range(1, 42)],
                                           "readings.duration": 3.0},
                                model_name="ownership")
    trials = [protocol.make_trial(config, "conv", "right", "sync", 0)]
    assert len(trials[0].blocks) == 42 and trials[0].hidden == ()
    result = wiring.run_batch(tiny_decoder(), trials, config)
    visual = result.values["stimulus.visual_time"][:, 0]
    touches = sorted(set(visual[np.isfinite(visual)].tolist()))
    # per block [10 k + 3, 10 (k + 1)]: touches at 10 k + 5, 7, 9 (the first block: 2, 4, 6, 8, 10); the last
    # block [413, 420]: 415, 417, 419
    expected = [2.0, 4.0, 6.0, 8.0, 10.0] + [10.0 * k + d for k in range(1, 42) for d in (5.0, 7.0, 9.0)]
    assert touches == pytest.approx(expected, abs=1e-9)


def test_any_number_of_blocks_is_accepted(tmp_path):
    path = tmp_path / "many.toml"
    path.write_text("[experiment]\nsteps = 5000\n[stimulations.sync]\nblocks = [" +
                    ", ".join(f"[{4 * k}, {4 * k + 2}]" for k in range(20)) + "]\n")
    config = configuration.load(path)
    assert len(protocol.make_trial(config, "conv", "left", "sync", 0).blocks) == 20
