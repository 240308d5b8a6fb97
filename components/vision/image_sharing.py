"""Images shared between trials and steps: exact grouping of a batch's identical images, and a bounded store of
what a network computed from an image, keyed by a digest of its bytes.

Trials of one lockstep batch that show the same rubber arm and ball see the same picture (the camera draws it
once and copies it, :class:`rhi.components.body.camera.Camera`), and a batch of the next participants sees the
same sequence of pictures again. A component that reads the image runs its network once per distinct image
(:func:`distinct`) and keeps the result for the next time that image comes (:class:`FeatureStore`).

- Grouping is exact: candidates by a few probed pixels, then every pixel of each member compared with its
  group's first image (bit for bit, as unsigned integers: -0.0 and 0.0, or two NaNs, are different images).
- The store's key is BLAKE2b (RFC 7693) of the image's bytes with 128-bit output: two different images share a
  key with probability about n^2 / 2^129 for n images stored (the birthday bound), nil for any run's n.
"""
from __future__ import annotations

import hashlib
from collections import OrderedDict

import numpy as np

PROBES = 16           # pixels compared first, spread over the image: most different images differ there already
DIGEST_BYTES = 16     # 128-bit BLAKE2b keys


def distinct(images: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The batch's distinct images, exactly: ``(first, inverse)`` with ``images[first[inverse]]`` equal to
    ``images`` bit for bit.

    Parameters
    ----------
    images : numpy.ndarray
        (B, ...) float32, C-contiguous rows.

    Returns
    -------
    first : numpy.ndarray
        (U,) int: the first trial showing each distinct image, ascending.
    inverse : numpy.ndarray
        (B,) int: each trial's position in ``first``.
    """
    if len(images) > 1 and images.strides[0] == 0:  # one picture broadcast to the batch (the camera's view)
        return np.zeros(1, int), np.zeros(len(images), int)
    rows = np.ascontiguousarray(images).reshape(len(images), -1).view(np.uint32)
    probes = rows[:, np.linspace(0, rows.shape[1] - 1, min(PROBES, rows.shape[1])).astype(int)]
    seen: dict[bytes, int] = {}
    leader = np.array([seen.setdefault(probe.tobytes(), b) for b, probe in enumerate(probes)])
    same = (rows == rows[leader]).all(axis=1)
    if not same.all():  # equal probes, different pictures: group those by every byte (rare)
        whole: dict[bytes, int] = {}
        for b in np.flatnonzero(~same):
            leader[b] = whole.setdefault(rows[b].tobytes(), b)
    first, inverse = np.unique(leader, return_inverse=True)
    return first, inverse.reshape(-1)


def digest(image: np.ndarray) -> bytes:
    """BLAKE2b-128 of an image's bytes, its shape and dtype (so a 32 x 32 and a 16 x 64 image never meet)."""
    hasher = hashlib.blake2b(digest_size=DIGEST_BYTES)
    hasher.update(f"{image.shape}{image.dtype.str}".encode())
    hasher.update(np.ascontiguousarray(image).data)
    return hasher.digest()


class FeatureStore:
    """What a network computed per image (one array each), least recently used dropped beyond ``memory_mb``.

    Keys are ``(network, image digest)`` pairs: the network's key (:func:`weights_key`, and whatever else its
    result depends on, such as torch's thread count) and :func:`digest` of the image.
    """

    def __init__(self, memory_mb: float):
        self.capacity, self.used = int(memory_mb * 2**20), 0
        self.entries: OrderedDict[tuple, np.ndarray] = OrderedDict()

    def get(self, key: tuple):
        """The stored array of ``key`` (now the most recently used), or None."""
        found = self.entries.get(key)
        if found is not None:
            self.entries.move_to_end(key)
        return found

    def put(self, key: tuple, value: np.ndarray) -> None:
        """Store ``value`` under ``key``, dropping the least recently used beyond the capacity."""
        if key in self.entries:
            return
        self.entries[key] = value
        self.used += value.nbytes
        while self.used > self.capacity and self.entries:
            self.used -= self.entries.popitem(last=False)[1].nbytes

    def clear(self) -> None:
        """Drop everything."""
        self.entries.clear()
        self.used = 0


def weights_key(module) -> bytes:
    """BLAKE2b-128 of a torch module's state (names, shapes, dtypes and values): the same weights, the same key."""
    hasher = hashlib.blake2b(digest_size=DIGEST_BYTES)
    for name, tensor in module.state_dict().items():
        array = tensor.detach().cpu().contiguous().numpy()
        hasher.update(f"{name}{array.shape}{array.dtype.str}".encode())
        hasher.update(array.data)
    return hasher.digest()
