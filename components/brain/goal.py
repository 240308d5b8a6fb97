"""A reach goal as an attractor of the belief, in body space (docs/reach.md).

The paper's released agent reaches by a visual attractor: an image of the arm at the goal pose, whose
prediction error with g(mu) is back-propagated through the decoder and added to mu_dot, not weighted by
gamma (``FepAgent.get_df_dmu_attr``: beta (attr - g(mu)) / sigma_mu, beta = 1, sigma_mu = 5e3, beside the
seen image's 1 / sigma_v_mu, sigma_v_mu = 1e4). In pixels that term is the decoder's visual drive with the
goal image in place of the camera's (a second decoder component computes it). In body space the goal is a
pose x_g with a variance Sigma_g (the pose encoder's reading of the same goal image), and the same free-energy
term 1/2 w (x_g - mu)^2 / Sigma_g has the gradient of :func:`body_space_attraction`.

:class:`GoalAttractor` outputs what the brains read as ``goal_drive``, ``goal_stiffness`` and ``goal_error``.
"""
from __future__ import annotations

import numpy as np

from ..component import StepFailure, Component
from ..variables import Variable


def body_space_attraction(mu, goal_pose, goal_variance, precision_ratio):
    """The released agent's attractor term in body space: w (x_g - mu) / Sigma_g, (B, 2) deg/s.

    Source: the released agent's ``get_df_dmu_attr`` (beta J^T (attr - g(mu)) / sigma_mu) with the generative
    map of a body-space observation, g = identity on the joint angles (as the causal model's seen-pose term,
    ``causal_brain.belief_rate``), so J = I. w = ``precision_ratio`` is the attractor's precision relative to the
    seen observation's: the released agent's beta sigma_v_mu / sigma_mu = 1e4 / 5e3 = 2.

    Parameters
    ----------
    mu, goal_pose : ndarray, (B, 2)
        Belief and goal pose x_g, deg.
    goal_variance : ndarray, (B, 2)
        Sigma_g, deg^2.
    precision_ratio : ndarray, (B,)
        w, 1.

    Returns
    -------
    ndarray, (B, 2)
        The pull on mu_dot, deg/s.
    """
    return precision_ratio[:, None] * (goal_pose - mu) / goal_variance


def body_space_goal_error(mu, goal_pose, goal_variance, precision_ratio):
    """The free energy of the body-space attractor, 1/2 w sum_j (x_g - mu)_j^2 / Sigma_g,j; its gradient in mu is
    minus :func:`body_space_attraction` (source as there).

    Parameters
    ----------
    mu, goal_pose, goal_variance, precision_ratio
        As :func:`body_space_attraction`.

    Returns
    -------
    ndarray, (B,)
        Dimensionless.
    """
    return 0.5 * precision_ratio * ((goal_pose - mu) ** 2 / goal_variance).sum(axis=1)


def goal_inputs() -> list[Variable]:
    """The three inputs by which a brain reads a reach goal's term (a :class:`GoalAttractor`, a goal decoder or a
    :class:`GoalOnset`): its pull on mu, its free-energy term and its stiffness; all 0 without a goal.

    Returns
    -------
    list of Variable
        ``goal_drive`` ((2,) deg/s), ``goal_error`` (1), ``goal_stiffness`` (1/s).
    """
    return [
        Variable("goal_drive", "input", start=(0.0, 0.0), unit="deg/s", type="Array", shape=(2,),
                 description="a reach goal's pull on mu, unweighted by gamma (0: no goal; docs/reach.md)"),
        Variable("goal_error", "input", start=0.0, unit="1", min=0.0, description="the goal's free-energy term (0: no goal)"),
        Variable("goal_stiffness", "input", start=0.0, unit="1/s", min=0.0,
                 description="the goal term's stiffness, for the stability guard (0: no goal)"),
    ]


class GoalAttractor(Component):
    """Belief and goal pose in, the goal's pull on the belief out (body space).

    Parameters
    ----------
    name : str
        The instance name in a system.
    """

    def __init__(self, name: str = "goal_attractor"):
        joint = dict(type="Array", shape=(2,))
        feed = dict(causality="output", depends_on=("mu", "goal_pose", "goal_pose_variance"))
        super().__init__(name, [
            Variable("precision_ratio", "parameter", start=2.0, unit="1", min=0.0,
                     description="w: the goal's precision relative to the seen pose's (released agent: 2)"),
            Variable("mu", "input", start=(0.0, 0.0), unit="deg", **joint, description="belief mu"),
            Variable("goal_pose", "input", start=(np.nan, np.nan), unit="deg", **joint,
                     description="x_g: the goal's joint angles (the pose encoder's reading of the goal image)"),
            Variable("goal_pose_variance", "input", start=(1.0, 1.0), unit="deg2", **joint,
                     description="Sigma_g: the variance of x_g"),
            Variable("goal_drive", unit="deg/s", **joint, **feed, description="w (x_g - mu) / Sigma_g"),
            Variable("goal_error", unit="1", **feed, description="1/2 w sum (x_g - mu)^2 / Sigma_g"),
            Variable("goal_stiffness", unit="1/s", causality="output", depends_on=("goal_pose_variance",),
                     description="largest w / Sigma_g, for the brain's stability guard"),
        ])

    def initialize(self):
        """Publish the goal's pull at the start belief (a step of length 0)."""
        self.step(0.0, 0.0)

    def step(self, t, h):
        """The goal's drive, error and stiffness at this step's belief mu (module notes)."""
        v = self.values
        for name in ("mu", "goal_pose", "goal_pose_variance"):
            if not np.all(np.isfinite(v[name])):
                raise StepFailure(f"{self.name}.{name} is not finite: {np.asarray(v[name]).tolist()}")
        if np.any(v["goal_pose_variance"] <= 0):
            raise StepFailure(f"{self.name}.goal_pose_variance must be positive")
        v["goal_drive"] = body_space_attraction(v["mu"], v["goal_pose"], v["goal_pose_variance"], v["precision_ratio"])
        v["goal_error"] = body_space_goal_error(v["mu"], v["goal_pose"], v["goal_pose_variance"], v["precision_ratio"])
        v["goal_stiffness"] = v["precision_ratio"] / v["goal_pose_variance"].min(axis=1)


def shown_from(t, onset, values):
    """``values`` where the goal is shown (t >= onset, per trial), 0 before: a goal that appears.

    Parameters
    ----------
    t : float
        Now, s.
    onset : ndarray, (B,)
        When the goal appears, s (1e-9 s early counts: the tick grid's rounding).
    values : ndarray, (B, ...)

    Returns
    -------
    ndarray, shaped as ``values``
    """
    shown = t >= onset - 1e-9
    return np.where(shown.reshape((-1,) + (1,) * (np.ndim(values) - 1)), values, 0.0)


class GoalOnset(Component):
    """A goal's pull that starts at ``onset``: goal_drive, goal_error, goal_stiffness passed through from then on,
    0 before (reaching after the illusion: the target appears when the arm is let go).

    Parameters
    ----------
    name : str
        The instance name in a system.
    """

    def __init__(self, name: str = "goal_onset"):
        joint = dict(type="Array", shape=(2,))
        super().__init__(name, [
            Variable("onset", "parameter", start=0.0, unit="s", min=0.0, description="when the goal appears"),
            Variable("drive", "input", start=(0.0, 0.0), unit="deg/s", **joint, description="the goal's pull"),
            Variable("error", "input", start=0.0, unit="1", description="the goal's free-energy term"),
            Variable("stiffness", "input", start=0.0, unit="1/s", description="the goal term's stiffness"),
            Variable("goal_drive", "output", unit="deg/s", depends_on=("drive",), **joint,
                     description="drive from onset on, else 0"),
            Variable("goal_error", "output", unit="1", depends_on=("error",), description="error from onset on"),
            Variable("goal_stiffness", "output", unit="1/s", depends_on=("stiffness",),
                     description="stiffness from onset on"),
        ])

    def initialize(self):
        """Publish the gated pull at the start time (a step of length 0)."""
        self.step(self.start_time, 0.0)

    def step(self, t, h):
        """Pass the goal's drive, error and stiffness on from the onset time, zero before it."""
        v = self.values
        v["goal_drive"] = shown_from(t, v["onset"], np.asarray(v["drive"], dtype=float))
        v["goal_error"] = shown_from(t, v["onset"], np.asarray(v["error"], dtype=float))
        v["goal_stiffness"] = shown_from(t, v["onset"], np.asarray(v["stiffness"], dtype=float))
