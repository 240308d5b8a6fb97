"""The paper's model (Rood, van Gerven & Lanillos 2020): the free-energy brain of eqs. 6-9 and its parameters."""
from __future__ import annotations

import numpy as np

from rhi.master.models.base import Model, TrialValues

# brain.parameter -> where its value comes from (rhi.master.models.base.Model.parameter_sources).
BRAIN_SOURCES = {
    "brain.proprioceptive_variance": "brain.proprioceptive_variance",
    "brain.gamma0": "brain.gamma0",
    "brain.mu0": "derived: the rest pose, rhi.components.body.kinematics.REST_POSE; the belief starts where the "
                 "real arm rests (docs/design.md fixes the geometry; the decoders are trained around it)",
    "brain.sync_sd": "brain.sync_sd",
    "brain.async_density": "brain.async_density",
    "brain.decay_rate": "brain.decay_rate",
    "brain.action_limit": "brain.action_limit",
    "brain.action_time_constant": "brain.action_time_constant",
    "brain.spatial_sd": "brain.spatial_sd",
}


def with_paper_sources(brain, own: dict) -> dict:
    """The parameter sources of a model whose ``brain`` shares parameters with the paper's: the paper's brain's
    sources (:data:`BRAIN_SOURCES`) of the parameters ``brain`` also declares, then the model's ``own``."""
    return {**{p: s for p, s in BRAIN_SOURCES.items() if p.partition(".")[2] in brain.variables}, **own}


def rest_belief(trials: TrialValues) -> np.ndarray:
    """(2,) deg: the belief's start, the rest pose (``brain.mu0``'s derived source)."""
    return np.array(trials.rest_pose, dtype=float)


class PaperModel(Model):
    """The paper's brain (:class:`rhi.components.brain.integrator.Brain`): vision as the decoder's pixel term,
    weighed by gamma from the touches' timing (eqs. 8-9)."""

    name = "paper"
    summary = "the paper's model: pixel-space vision weighed by a common-cause belief from the touches' timing"
    settings_file = "paper.toml"
    parameter_sources = BRAIN_SOURCES

    def brain(self):
        """A new :class:`~rhi.components.brain.integrator.Brain`."""
        from rhi.components.brain.integrator import Brain
        return Brain()

    def parameters(self, trials: TrialValues) -> dict:
        """The plain sources' values and the start belief at rest."""
        return {**super().parameters(trials), "brain.mu0": rest_belief(trials)}
