"""The brain contract: the variables :meth:`rhi.components.brain.base.BeliefBrain.step` reads and writes, declared
once for every brain (:func:`contract`), and the decoder's pixel term as a brain that reads it declares it
(:func:`pixel_inputs`); :data:`JOINT` and :data:`STATE`, the keywords of a joint pair and of a state output.
"""
from __future__ import annotations

from types import MappingProxyType

import numpy as np

from .goal import goal_inputs
from ..variables import Variable

JOINT = MappingProxyType(dict(type="Array", shape=(2,)))  # a (shoulder, elbow) pair per trial
STATE = MappingProxyType(dict(causality="output", depends_on=()))  # an output of the state: no direct feedthrough


def contract(gamma: str, free_energy: str = "F at the step's start mu") -> dict[str, list[Variable]]:
    """The variables :meth:`BeliefBrain.step` reads and writes, declared once for every brain.

    Parameters
    ----------
    gamma : str
        What the model's ``gamma`` is (its description): the weight of vision, ownership, ...
    free_energy : str
        What the model's ``free_energy`` sums.

    Returns
    -------
    dict of str to list of Variable
        ``"parameters"``: Sigma_p, mu0, the action law's limit and tau; ``"inputs"``: s_p (q_shoulder,
        q_elbow), the reach goal's term and the touch events; ``"outputs"``: mu, the action a and its rate,
        gamma and the free energy.
    """
    return {
        "parameters": [
            Variable("proprioceptive_variance", "parameter", start=1.0, unit="deg2", min=0.0,
                     description="Sigma_p, proprioceptive variance (1/Sigma_p is the belief's relaxation rate, 1/s)"),
            Variable("mu0", "parameter", start=(0.0, 0.0), unit="deg", **JOINT,
                     description="initial belief (shoulder, elbow); the master sets the rest pose"),
            Variable("action_limit", "parameter", start=1.0, unit="deg/s", min=0.0,
                     description="the action is clipped to [-action_limit, action_limit]"),
            Variable("action_time_constant", "parameter", start=0.1, unit="s", min=0.0,
                     description="tau of the action law a <- a + dt (a_dot - a/tau): the leaky (reflex) "
                                 "action; inf = the paper's eq. 7, a pure integrator"),
        ],
        "inputs": [
            Variable("q_shoulder", "input", start=np.nan, unit="deg",
                     description="s_p: sensed shoulder angle (NaN until the body feeds it)"),
            Variable("q_elbow", "input", start=np.nan, unit="deg",
                     description="s_p: sensed elbow angle (NaN until the body feeds it)"),
            *goal_inputs(),
            Variable("visual_time", "input", start=-np.inf, unit="s",
                     description="time of the last observed visual touch event (-inf: none yet)"),
            Variable("tactile_time", "input", start=-np.inf, unit="s",
                     description="time of the last observed tactile event (-inf: none yet)"),
        ],
        "outputs": [
            Variable("mu", unit="deg", **JOINT, **STATE, description="belief of the joint angles (shoulder, elbow)"),
            Variable("u_shoulder", unit="deg/s", **STATE, description="action a: commanded shoulder velocity"),
            Variable("u_elbow", unit="deg/s", **STATE, description="action a: commanded elbow velocity"),
            Variable("action_rate", unit="deg/s2", **JOINT, **STATE, description="a_dot (shoulder, elbow)"),
            Variable("gamma", unit="1", min=0.0, max=1.0, **STATE, description=gamma),
            Variable("free_energy", unit="1", **STATE, description=free_energy),
        ],
    }


def pixel_inputs(note: str = "") -> list[Variable]:
    """The decoder's pixel term as a brain reads it (the paper's eq. 6, :mod:`rhi.components.vision.component`).

    Parameters
    ----------
    note : str
        Appended to each description (e.g. when the brain reads the term).

    Returns
    -------
    list of Variable
        ``visual_drive`` ((2,) deg/s), ``visual_error`` (1), ``visual_stiffness`` (1/s).
    """
    return [
        Variable("visual_drive", "input", start=(0.0, 0.0), unit="deg/s", **JOINT,
                 description="J^T (s_v - g(mu)) / Sigma_v from the decoder, at this step's mu" + note),
        Variable("visual_error", "input", start=0.0, unit="1", min=0.0,
                 description="1/2 e^T Sigma_v^-1 e from the decoder, e = s_v - g(mu), at this step's mu" + note),
        Variable("visual_stiffness", "input", start=0.0, unit="1/s", min=0.0,
                 description="largest eigenvalue of J^T J / Sigma_v, for the stability guard" + note),
    ]
