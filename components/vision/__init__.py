"""The visual decoder: the paper's ConvDecoder and VAE, their training, and the Decoder component.

Modules: :mod:`networks` (the shared decoder definition, the VAE encoder, presets),
:mod:`training` (the seeded training loop), :mod:`checkpoint` (safe save and load),
:mod:`component` (the co-simulation component, forward-mode Jacobians).
Training data come from the body's camera; that wiring lives in ``master/training_data.py``.
"""
import os

# Torch's OpenMP threads spin while waiting at barriers by default. On a machine whose cores
# are shared with other processes that made training 10x slower (measured on 2 cores); passive
# waiting costs little when the cores are free. Read once, when torch loads: hence before it.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from components.vision.checkpoint import CheckpointError  # noqa: E402  (after the setting above)
from components.vision.component import Decoder, GenerativeModel, jacobian_images  # noqa: E402

__all__ = ["Decoder", "GenerativeModel", "jacobian_images", "CheckpointError"]
