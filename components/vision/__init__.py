"""The visual decoder: the paper's ConvDecoder and VAE, their training, and the Decoder component.

Modules: :mod:`networks` (the shared decoder definition, the VAE encoder, presets),
:mod:`training` (the seeded training loop), :mod:`checkpoint` (safe save and load),
:mod:`component` (the co-simulation component, forward-mode Jacobians).
Training data come from the body's camera; that wiring lives in ``master/decoders/training_data.py``.
"""
import importlib

_HOME = {"Decoder": "component", "GenerativeModel": "component", "jacobian_images": "component",
         "CheckpointError": "checkpoint"}  # each name the package exports, and its module
__all__ = list(_HOME)


def __getattr__(name):
    """The names above, loaded on first use (PEP 562): a module of this package that needs no torch, such as
    :mod:`limits`, which the configuration reads, then loads none."""
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f".{_HOME[name]}", __name__), name)
