"""The batched arm in the protocol: its bias against the pymunk arm on the reported statistics (drift, force, onset).

The same trials (same seeds) run with each arm; the bias of a cell is the mean of the paired differences. It must
be below a tenth of the pymunk arm's between-trial sd in the cell, or, where that sd is smaller than the pymunk
arm's own discretisation error (a cell whose trials barely differ, ~1e-7 N), below that error: Richardson's estimate
for a first-order method (Chipmunk's semi-implicit Euler), twice the paired difference between the pymunk arm at 20
sub-steps (the default) and at 40 (error(dt) = C dt + O(dt^2), so error(dt) ~ 2 (x_dt - x_dt/2)).
"""
import numpy as np
import pytest

from rhi.master import config as configuration
from rhi.master.decoders.cache import ensure_checkpoints
from rhi.master.runtime.context import RunContext
from rhi.master.tasks.illusion import runner
from rhi.master.tasks.illusion.measures import end_of_trial

STATISTICS = {"paper": ("drift_cm", "force_x_n"), "ownership": ("drift_cm", "force_x_n", "ownership_onset_s")}


def finals(config, checkpoints, body, substeps):
    """The trials and their end-of-trial statistics with ``body`` (None: the pymunk arm) at ``substeps``."""
    config = configuration.merge(config, {"body": {"substeps": substeps}})
    kept, times, per_step, _, failures = runner.run(config, checkpoints, body, RunContext(processes=1))
    assert not failures
    return kept, end_of_trial(times, per_step)


@pytest.mark.parametrize("model", ["paper", "ownership"])
def test_the_batched_arm_s_bias_is_below_a_tenth_of_the_between_trial_sd(model):
    # The shipped conv decoder and pose encoder (64 px): nothing trained. Three trials a cell, 6 s each: past the
    # synchronous cells' ownership onsets (about 3-4 s).
    config = configuration.load(model_name=model, overrides={"experiment.trials": 3, "experiment.steps": 300,
                                                             "experiment.decoders": ["conv"]})
    checkpoints, _ = ensure_checkpoints(config, progress=False)
    trials, pymunk_s = finals(config, checkpoints, None, 20)
    (mine_trials, mine), (_, finer) = finals(config, checkpoints, "batched", 20), finals(config, checkpoints, None, 40)
    assert mine_trials == trials
    cells = sorted({(t.decoder, t.condition, t.stimulation) for t in trials})
    for statistic in STATISTICS[model]:
        reference, batched, halved = (np.asarray(run[statistic]) for run in (pymunk_s, mine, finer))
        assert np.array_equal(np.isnan(reference), np.isnan(batched)), statistic  # an onset in the same trials
        for cell in cells:
            members = [n for n, t in enumerate(trials) if (t.decoder, t.condition, t.stimulation) == cell]
            x, y, z = reference[members], batched[members], halved[members]
            seen = ~np.isnan(x)
            if seen.sum() < 2:  # no sd (an asynchronous cell with one onset or none)
                continue
            bias = abs(np.mean(y[seen] - x[seen]))
            own_error = 2 * abs(np.mean(z[seen] - x[seen]))
            assert bias <= max(np.std(x[seen], ddof=1) / 10, own_error), (statistic, cell, bias, own_error)
