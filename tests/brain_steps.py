"""The paper's brain stepped by hand, without a master: for tests/test_brain*.py."""
import math

import numpy as np

from components.brain import Brain
from components.component import Status

H = 0.02


def started(batch=1, inputs=None, **parameters):
    """A brain past initialization, parameters and inputs set by hand (no master); the paper's action
    law (action_time_constant = inf) unless the test sets another."""
    brain = Brain()
    brain.instantiate(batch)
    for name, value in {"action_time_constant": np.inf, **parameters}.items():
        brain.set(name, value)
    brain.setup_experiment(0.0)
    brain.enter_initialization_mode()
    for name, value in {"q_shoulder": 0.0, "q_elbow": 0.0, **(inputs or {})}.items():
        brain.set(name, value)
    brain.exit_initialization_mode()
    assert brain.last_reason == ""
    return brain


def advance(brain, t, h=H, **inputs):
    for name, value in inputs.items():
        brain.set(name, value)
    status = brain.do_step(t, h)
    assert status == Status.OK, brain.last_reason
    return brain


def normal_pdf(x, sd=0.2):
    return math.exp(-0.5 * (x / sd) ** 2) / (sd * math.sqrt(2 * math.pi))
