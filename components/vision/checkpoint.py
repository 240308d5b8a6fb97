"""Saving and loading trained decoders, safely.

A checkpoint is one file written by ``torch.save`` holding only tensors, strings and
numbers, so it loads with ``torch.load(weights_only=True)`` and never unpickles an
arbitrary object::

    {"format": "rhi-visual-decoder/1", "metadata": "<JSON text>", "weights": {name: tensor}}

The metadata (JSON) records the decoder kind and preset sizes, the resolution, the
training ranges (rest pose and half-ranges, degrees), the training-data hash, the
validation MSE and the training settings (no wall time: same settings, same bytes). Every problem with a
file (missing, truncated, not a checkpoint, wrong shapes, not matching the camera)
raises one :class:`CheckpointError` naming the file and what is wrong.

Example::

    with open("conv.pt", "wb") as file:
        write(file, model, metadata)
    model, metadata = load("conv.pt", resolution=64, rest_pose=(147.7, -91.2))
"""
from __future__ import annotations

import json
import math
import os
import pickle
import stat
import sys
import warnings
import zipfile
from typing import BinaryIO

import torch

from ..archives import ArchiveError, check_archive
from ..component import ComponentError
from .networks import VisualModel, build, sizes_from_dict

FORMAT = "rhi-visual-decoder/1"
REQUIRED = {"kind": str, "preset": str, "sizes": dict, "resolution": int, "rest_pose": list,
            "half_ranges": list, "data_hash": str, "validation_mse": float}
ZIP_MAGIC = b"PK\x03\x04"  # torch.save writes a zip archive
ANGLE_TOLERANCE = 1e-6  # deg: ranges are stored as JSON floats, which round-trip exactly


class CheckpointError(ComponentError):
    """A decoder checkpoint that cannot be used; the message names the file and the reason."""


def write(file: BinaryIO, model: VisualModel, metadata: dict) -> None:
    """Write ``model``'s weights and ``metadata`` (JSON-able) into the open binary ``file``.

    The caller makes the file whole or absent (the master writes through a temporary file and a rename).
    """
    missing = [key for key in REQUIRED if key not in metadata]
    if missing:
        raise ValueError(f"checkpoint metadata lacks {', '.join(missing)}")
    payload = {"format": FORMAT, "metadata": json.dumps(metadata, sort_keys=True),
               "weights": {name: tensor.detach().cpu().clone() for name, tensor in model.state_dict().items()}}
    torch.save(payload, file)


def load(path: str | os.PathLike, resolution: int | None = None, rest_pose=None,
         half_ranges=None) -> tuple[VisualModel, dict]:
    """The model (eval mode, float32, gradients off) and metadata stored at ``path``.

    resolution, rest_pose, half_ranges: what the camera and the body use now; when
    given, a checkpoint trained for anything else is rejected.
    """
    payload = _payload(path)
    metadata = _metadata(path, payload)
    check_matches(path, metadata, resolution, rest_pose, half_ranges)
    weights = payload["weights"]
    if not isinstance(weights, dict) or not all(isinstance(w, torch.Tensor) for w in weights.values()):
        raise CheckpointError(f"{path}: its weights are not a dictionary of tensors")
    sizes = _sizes(path, metadata)
    try:
        with torch.device("meta"):  # the architecture's shapes, no memory: compared with the stored weights first
            shapes = build(metadata["kind"], metadata["preset"], metadata["resolution"], sizes=sizes).state_dict()
    except (KeyError, TypeError, ValueError, ComponentError) as error:
        raise CheckpointError(f"{path}: its architecture cannot be built ({error})") from None
    wanted, stored = sum(t.numel() for t in shapes.values()), sum(w.numel() for w in weights.values())
    if wanted != stored:
        raise CheckpointError(f"{path}: its weights do not fit a {metadata['kind']} decoder, preset "
                              f"{metadata['preset']!r} at {metadata['resolution']} px (its metadata describes "
                              f"{wanted} numbers, it stores {stored})")
    model = build(metadata["kind"], metadata["preset"], metadata["resolution"], sizes=sizes)
    try:
        model.load_state_dict(weights, strict=True)
    except RuntimeError as error:
        first = str(error).strip().splitlines()
        raise CheckpointError(f"{path}: its weights do not fit a {metadata['kind']} decoder, preset "
                              f"{metadata['preset']!r} at {metadata['resolution']} px "
                              f"({' '.join(line.strip() for line in first[1:3]) or first[0]})") from None
    if not all(torch.isfinite(w).all() for w in weights.values() if w.is_floating_point()):
        raise CheckpointError(f"{path}: its weights contain NaN or infinity")
    model.float().eval().requires_grad_(False)
    return model, metadata


def read_metadata(path) -> dict:
    """The metadata of the checkpoint at ``path`` (CheckpointError if it is not one)."""
    return _metadata(path, _payload(path))


# Bounds on the sizes a checkpoint's metadata may ask for, before anything is built: eight times the paper
# preset's widths (hidden 1024, 128 channels, 4 stages) and a resolution of 1024 px.
MAX_HIDDEN, MAX_CHANNELS, MAX_STAGES, MAX_RESOLUTION = 8192, 1024, 8, 1024


def _sizes(path, metadata: dict):
    """The network sizes of the metadata, each a positive integer within the bounds above."""
    sizes, resolution = metadata["sizes"], metadata["resolution"]
    hidden, channels = sizes.get("hidden"), sizes.get("channels")
    whole = (lambda v, top: isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= top)
    if not whole(hidden, MAX_HIDDEN):
        raise CheckpointError(f"{path}: metadata sizes.hidden = {str(hidden)[:40]} must be an integer in 1..{MAX_HIDDEN}")
    if not (isinstance(channels, list) and 1 <= len(channels) <= MAX_STAGES
            and all(whole(c, MAX_CHANNELS) for c in channels)):
        raise CheckpointError(f"{path}: metadata sizes.channels = {str(channels)[:60]} must be 1 to {MAX_STAGES} "
                              f"integers in 1..{MAX_CHANNELS}")
    if not whole(resolution, MAX_RESOLUTION) or not whole(sizes.get("resolution"), MAX_RESOLUTION):
        raise CheckpointError(f"{path}: metadata resolution must be an integer in 1..{MAX_RESOLUTION}")
    return sizes_from_dict(sizes)


def check_matches(path, metadata: dict, resolution=None, rest_pose=None, half_ranges=None) -> None:
    """CheckpointError unless the checkpoint's resolution and ranges equal the given ones."""
    if resolution is not None and metadata["resolution"] != resolution:
        raise CheckpointError(f"{path}: trained at resolution {metadata['resolution']} px but the camera "
                              f"renders {resolution} px; retrain with resolution = {resolution}")
    for name, expected in (("rest_pose", rest_pose), ("half_ranges", half_ranges)):
        if expected is None:
            continue
        stored = metadata[name]
        if len(stored) != len(expected) or any(abs(a - float(b)) > ANGLE_TOLERANCE
                                               for a, b in zip(stored, expected)):
            raise CheckpointError(f"{path}: trained with {name} = {_fmt(stored)} deg but the body "
                                  f"uses {_fmt(expected)} deg; retrain the decoder")


def _payload(path) -> dict:
    try:
        kind = os.stat(path).st_mode  # by its kind, before opening: a FIFO would wait for a writer forever
        if stat.S_ISDIR(kind):
            raise IsADirectoryError
        if not stat.S_ISREG(kind):
            raise CheckpointError(f"{path}: is not a regular file (a FIFO, a device or a socket)")
        with open(path, "rb") as file:
            head = file.read(4)
    except FileNotFoundError:
        raise CheckpointError(f"{path}: no such checkpoint file") from None
    except IsADirectoryError:
        raise CheckpointError(f"{path}: is a folder, not a checkpoint file") from None
    except OSError as error:
        raise CheckpointError(f"{path}: cannot be read ({error.strerror or error})") from None
    if head != ZIP_MAGIC:
        raise CheckpointError(f"{path}: not a decoder checkpoint (not a zip archive as torch.save writes)")
    try:
        check_archive(path)
    except ArchiveError as error:
        damaged = "not a readable zip archive" in str(error)
        raise CheckpointError(f"{path}: {'truncated or damaged checkpoint: ' * damaged}{error}") from None
    try:
        with warnings.catch_warnings():  # torch warns about pickle protocols before refusing a file
            warnings.simplefilter("ignore", UserWarning)
            payload = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        raise CheckpointError(f"{path}: not a decoder checkpoint (it holds objects other than tensors, "
                              "strings and numbers, which are never unpickled)") from None
    except (RuntimeError, EOFError, OSError, ValueError, zipfile.BadZipFile, UnicodeDecodeError, AttributeError,
            ImportError, IndexError, KeyError, TypeError) as error:
        reason = str(error).strip().splitlines()[0][:120] if str(error).strip() else type(error).__name__
        raise CheckpointError(f"{path}: truncated or damaged checkpoint ({reason})") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a decoder checkpoint (no {FORMAT!r} format tag)")
    return payload


def _metadata(path, payload: dict) -> dict:
    try:
        metadata = json.loads(payload["metadata"])
    except (KeyError, TypeError, ValueError):
        raise CheckpointError(f"{path}: its metadata is missing or is not JSON") from None
    except RecursionError:  # JSON nested deeper than Python's recursion limit: not metadata rhi wrote
        raise CheckpointError(f"{path}: its metadata nests over Python's recursion limit of "
                              f"{sys.getrecursionlimit()} deep (rhi writes it at most 3 deep)") from None
    if not isinstance(metadata, dict):
        raise CheckpointError(f"{path}: its metadata is not a JSON object")
    for key, kind in REQUIRED.items():
        value = metadata.get(key)
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = metadata[key] = float(value)
        if not isinstance(value, kind) or isinstance(value, bool):
            raise CheckpointError(f"{path}: metadata {key!r} is missing or not a {kind.__name__}")
    for key in ("rest_pose", "half_ranges"):
        values = metadata[key]
        if len(values) != 2 or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
            raise CheckpointError(f"{path}: metadata {key!r} = {values!r} is not two finite angles")
    if not all(v > 0 for v in metadata["half_ranges"]):
        raise CheckpointError(f"{path}: metadata 'half_ranges' = {metadata['half_ranges']!r} must be positive")
    return metadata


def _fmt(values) -> str:
    return "(" + ", ".join(f"{float(v):.6g}" for v in values) + ")"
