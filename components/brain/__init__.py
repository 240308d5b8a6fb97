"""The brain component: free-energy integrator of belief and action, and causal inference of gamma."""
from components.brain.integrator import Brain

__all__ = ["Brain"]
