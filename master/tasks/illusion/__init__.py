"""The rubber-hand illusion task: its system and one lockstep batch (wiring), the runner, measures, the run in memory
and into DIR (publish), the fast check.

The one obvious call, in memory (``result.write(DIR)`` publishes what ``rhi experiment`` writes)::

    from rhi.master.tasks.illusion import run_experiment
    from rhi.master import config
    result = run_experiment(config.load(quick=True))
    result.final["drift_cm"]                   # (trials,) cm, in the order of result.trials

By hand, one lockstep batch::

    from rhi.master.decoders.cache import decoder_component
    trials = plan(cfg)
    batch = run_batch(decoder_component("conv", path, cfg), trials, cfg)
    drift = measures(batch)["drift_cm"]        # (steps + 1, len(trials))
"""
from rhi.master.runtime.context import RunContext
from rhi.master.tasks.illusion.measures import measures
from rhi.master.config.protocol import Trial, make_trial, plan, rubber_pose, trial_seed
from rhi.master.tasks.illusion.runner import run, trial_outcome, without_failures
from rhi.master.tasks.illusion.wiring import CONNECTIONS, RECORD, build_system, parameters, run_batch


def run_experiment(config=None, body=None, context=None, workers=None):
    """The protocol in memory: :func:`rhi.master.tasks.illusion.publish.run_experiment` (imported when called: it
    brings the figures and the decoders' training)."""
    from rhi.master.tasks.illusion.publish import run_experiment as run_protocol
    return run_protocol(config, body, context, workers)


__all__ = ["run_experiment", "RunContext", "Trial", "make_trial", "plan", "rubber_pose", "trial_seed", "CONNECTIONS",
           "RECORD", "build_system", "parameters", "run_batch", "measures", "run", "trial_outcome", "without_failures"]
