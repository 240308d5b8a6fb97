"""The rubber-hand experiment on the engine: protocol and seeds, wiring, measures, decoders, training data.

Example::

    config = config.load(quick=True)
    trials = plan(config)
    result = run_batch(decoder_component("conv", path, config), trials, config)
    drift = measures(result)["drift_cm"]       # (steps + 1, len(trials))
"""
from master.experiment.measures import measures
from master.experiment.protocol import Trial, make_trial, plan, rubber_pose, trial_seed
from master.experiment.runner import run, trial_outcome, without_failures
from master.experiment.wiring import CONNECTIONS, RECORD, build_system, parameters, run_batch

__all__ = ["Trial", "make_trial", "plan", "rubber_pose", "trial_seed", "CONNECTIONS", "RECORD", "build_system",
           "parameters", "run_batch", "measures", "run", "trial_outcome", "without_failures"]
