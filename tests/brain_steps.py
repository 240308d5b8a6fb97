"""The brains stepped by hand, without a master: for tests/test_brain*.py."""
import math
from pathlib import Path

import numpy as np

from rhi.components.brain import Brain
from rhi.components.component import Status
from rhi.master import models

H = 0.02
EXAMPLE_MODEL = f"{Path(__file__).resolve().parents[1] / 'examples' / 'my_model.py'}:FixedGamma"

# Every registered model's brain class and the example model's, for the tests every brain must pass
# (tests/test_brain_guards.py).
BRAINS = list(dict.fromkeys(type(models.get(name).brain()) for name in (*models.names(), EXAMPLE_MODEL)))


def started(batch=1, inputs=None, kind=Brain, **parameters):
    """A brain of class ``kind`` past initialization, parameters and inputs set by hand (no master); the
    paper's action law (action_time_constant = inf) unless the test sets another. Every input whose start
    value is NaN (s_p, a seen pose or hand: what a master would connect) starts at 0 unless ``inputs`` sets it."""
    brain = kind()
    brain.instantiate(batch)
    for name, value in {"action_time_constant": np.inf, **parameters}.items():
        brain.set(name, value)
    brain.setup_experiment(0.0)
    brain.enter_initialization_mode()
    unset = {name: np.zeros_like(brain.get(name)) for name, variable in brain.variables.items()
             if variable.causality == "input" and np.isnan(brain.get(name)).any()}
    for name, value in {**unset, **(inputs or {})}.items():
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


def outputs(brain):
    """Copies of every output of ``brain``, by name: its state as a master sees it."""
    return {name: np.array(brain.get(name), copy=True) for name, variable in brain.variables.items()
            if variable.causality == "output"}


def normal_pdf(x, sd=0.2):
    return math.exp(-0.5 * (x / sd) ** 2) / (sd * math.sqrt(2 * math.pi))
