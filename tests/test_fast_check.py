"""The fast mode's check (rhi.master.tasks.illusion.fast_check): its verdict's numbers, where it is kept, when it is redone."""
import contextlib
import io
import json

import numpy as np
import pytest

from rhi.master import config as configuration
from rhi.master.runtime.logs import configured
from rhi.master.tasks.illusion import fast_check
from rhi.master.tasks.illusion import runner
from rhi.master.decoders.cache import checkpoint_path
from rhi.master.tasks.illusion.measures import end_of_trial
from rhi.master.config.protocol import make_trial
from rhi.master.runtime.context import RunContext


def quick_config(quick_cache, folder, monkeypatch):
    """The --quick configuration over a copy of the session's decoders in the cache ``folder``."""
    for path in quick_cache.glob("*.pt"):
        (folder / path.name).write_bytes(path.read_bytes())
    monkeypatch.setenv("RHI_CACHE", str(folder))
    config = configuration.load(quick=True, overrides={"experiment.decoders": ["conv"], "decoder.fast": True})
    return config, {"conv": checkpoint_path("conv", config, must_exist=True)}


@pytest.fixture
def quick(quick_cache, monkeypatch, tmp_path):
    """The --quick configuration over a copy of the session's decoders in a cache of this test's own."""
    return quick_config(quick_cache, tmp_path, monkeypatch)


@pytest.fixture(scope="module")
def checked(quick_cache, tmp_path_factory):
    """The conv decoder checked once, in a cache of the module's own: its configuration, checkpoints, verdict, what
    it said on stderr (logging as the command line sets it up), and the cache (which holds the verdict), for the
    tests that read that one check."""
    folder = tmp_path_factory.mktemp("fast_check")
    said = io.StringIO()
    with pytest.MonkeyPatch.context() as monkeypatch, contextlib.redirect_stderr(said), configured(0):
        config, checkpoints = quick_config(quick_cache, folder, monkeypatch)
        verdict = fast_check.verdicts(config, checkpoints, progress=True)["conv"]
    return config, checkpoints, verdict, said.getvalue(), folder


def test_the_verdict_compares_the_fast_and_exact_drifts_of_the_protocol_s_own_trials(checked):
    config, checkpoints, verdict, said, folder = checked
    checked = len(verdict["trials"])
    assert said.startswith(f"checking the fast mode of the conv decoder: {checked} trials each, exact and fast "
                           "(once per decoder and settings)\n")
    steps = config["experiment"]["steps"]  # then a bar of the steps of each run, exact first
    assert f"conv fast check: exact x{checked}:   0%|          | 0/{steps}" in said
    assert said.index("fast check: exact") < said.index(f"conv fast check: fast x{checked}:   0%|          | 0/{steps}")
    exact = np.array(verdict["drift_exact_cm"])
    fast = np.array(verdict["drift_fast_cm"])
    assert verdict["relative_error"] == pytest.approx(np.abs(fast - exact).max() / np.abs(exact).max(), rel=1e-12)
    assert verdict["fast"] == (verdict["relative_error"] <= fast_check.DRIFT_BOUND)
    # The exact drifts are those of the experiment run exact: same trials and seeds, in a batch of another size
    # (the decoder's float32 sums then differ in their last bits, hence the tolerance).
    trials, times, per_step, _, _ = runner.run({**config, "decoder": {**config["decoder"], "fast": False}},
                                               checkpoints, context=RunContext(processes=1))
    final = end_of_trial(times, per_step)["drift_cm"]
    for name, drift in zip(verdict["trials"], exact):
        condition, stimulation, index = name.split()
        assert drift == pytest.approx(final[trials.index(make_trial(config, "conv", condition, stimulation,
                                                                    int(index)))], rel=1e-6, abs=1e-9)
    stored = list(folder.glob("fast-check-conv-*.json"))
    assert len(stored) == 1 and json.loads(stored[0].read_text()) == verdict


def test_a_stored_verdict_is_reused_and_a_trial_setting_asks_for_a_new_one(checked, monkeypatch):
    config, checkpoints, verdict, _, folder = checked
    monkeypatch.setenv("RHI_CACHE", str(folder))  # the module's check stored its verdict there
    monkeypatch.setattr(fast_check, "check", lambda *job: pytest.fail("checked again"))
    assert fast_check.verdicts(config, checkpoints) == {"conv": verdict}
    more_trials = {**config, "experiment": {**config["experiment"], "trials": 4}}
    assert fast_check.verdicts(more_trials, checkpoints) == {"conv": verdict}  # the trial count moves no checked trial
    assert fast_check.verdict_key(checkpoints["conv"], config) != fast_check.verdict_key(
        checkpoints["conv"], {**config, "decoder": {**config["decoder"], "visual_variance": 30.0}})


def test_a_decoder_beyond_the_bound_runs_exact_and_fast_false_checks_nothing(quick, monkeypatch):
    config, checkpoints = quick
    monkeypatch.setattr(fast_check, "DRIFT_BOUND", -1.0)  # no error is within it
    verdict = fast_check.verdicts(config, checkpoints)["conv"]
    assert verdict["fast"] is False and "beyond" in verdict["reason"]
    monkeypatch.setattr(fast_check, "check", lambda *job: pytest.fail("checked with fast = false"))
    exact = {**config, "decoder": {**config["decoder"], "fast": False}}
    assert fast_check.verdicts(exact, checkpoints) == {"conv": {"fast": False, "reason": "decoder.fast = false"}}
