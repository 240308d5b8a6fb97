"""The brain components: the paper's free-energy integrator of belief and action with causal inference of gamma
(``Brain``), the causal model's brain (``causal_brain.CausalBrain``), both on one base of step and guards
(``base.BeliefBrain``)."""
from .integrator import Brain

__all__ = ["Brain"]
