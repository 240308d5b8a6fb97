"""The visual decoder: the paper's ConvDecoder and VAE, their training, and the Decoder component.

Modules: :mod:`networks` (the shared decoder definition, the VAE encoder, presets),
:mod:`training` (the seeded training loop), :mod:`checkpoint` (safe save and load),
:mod:`component` (the co-simulation component, forward-mode Jacobians).
Training data come from the body's camera; that wiring lives in ``master/decoders/training_data.py``.
"""
from .checkpoint import CheckpointError
from .component import Decoder, GenerativeModel, jacobian_images

__all__ = ["Decoder", "GenerativeModel", "jacobian_images", "CheckpointError"]
