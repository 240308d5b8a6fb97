"""The body a configuration chooses (``experiment.body``): checked against the registered variants, run by the fit's
(and every sweep's) lockstep batches, and the default leaving the trials' ids as they were before the key."""
import numpy as np
import pytest

from rhi.components.body.batched import BatchedArm
from rhi.master import config as configuration
from rhi.master.config.bodies import VARIANTS
from rhi.master.cosim import ConfigError

DATA = """participant,condition,stimulation,drift_cm
p,left,sync,-1.0
"""
FIT = """[experiment]
steps = 4
body = "{body}"
[fit]
simulations = 10
calibration = 0
participants_per_batch = 2
[fit.parameters."brain.proprioceptive_variance"]
prior = "log-uniform"
low = 0.5
high = 2.0
"""


def plan_of(tmp_path, body):
    from rhi.master.fit.data import read_data
    from rhi.master.fit.plan import read_plan

    (tmp_path / "d.csv").write_text(DATA)
    (tmp_path / "fit.toml").write_text(FIT.format(body=body))
    data = read_data(str(tmp_path / "d.csv"))
    return read_plan(str(tmp_path / "fit.toml"), data), data


def test_an_unknown_body_is_refused_in_one_line_naming_the_variants(tmp_path):
    with pytest.raises(ConfigError, match=f"experiment.body = 'chipmunk' is not a body variant; choose one of "
                                          f"{', '.join(VARIANTS)}") as refused:
        plan_of(tmp_path, "chipmunk")
    assert "\n" not in str(refused.value)


def test_the_fit_s_simulations_step_the_configured_body(tmp_path, monkeypatch):
    from rhi.master.fit import memory

    steps = []  # (batch size) of each BatchedArm step
    original = BatchedArm.step

    def counted(self, t, h):
        steps.append(self.batch_size)
        return original(self, t, h)
    monkeypatch.setattr(BatchedArm, "step", counted)
    theta = np.log([[0.7], [1.4]])  # two participants, one lockstep batch of their two trials
    drifts = {}
    for body in ("native", "batched"):
        steps.clear()
        plan, data = plan_of(tmp_path, body)
        drifts[body] = memory.simulate(plan, data, theta)
        # the pymunk arm's batch never touches the batched arm; the batched one steps both trials every step
        assert steps == ([] if body == "native" else [2] * 4), body
    assert np.isfinite(drifts["batched"]).all()


def test_the_default_body_leaves_the_trial_ids_of_a_configuration_without_the_key():
    from rhi.master.sweeps import plan as sweeps

    base = configuration.load(quick=True)
    assert base["experiment"]["body"] == "native"
    before = {**base, "experiment": {k: v for k, v in base["experiment"].items() if k != "body"}}  # the key's absence
    batched = configuration.merge(base, {"experiment": {"body": "batched"}})
    planned = [sweeps.build(config, [{}]) for config in (base, before, batched)]
    assert [t.id for t in planned[0].trials] == [t.id for t in planned[1].trials]
    assert planned[0].fingerprint == planned[1].fingerprint
    assert not {t.id for t in planned[0].trials} & {t.id for t in planned[2].trials}


def test_rhi_experiment_and_rhi_power_s_batches_take_the_configured_body_unless_one_is_given():
    from rhi.master.tasks.illusion.runner import body_factory

    base = configuration.load(quick=True)
    batched = configuration.merge(base, {"experiment": {"body": "batched"}})
    assert body_factory(None, base) == (None, None)  # the default: the task's own pymunk arm, as before the key
    made, declared = body_factory(None, batched)
    assert made is BatchedArm and declared == set(BatchedArm().variables)
    assert body_factory("kinematic", batched)[0] is not BatchedArm  # --body wins over the configuration
