"""Planar 2-link arm kinematics (pure numpy, vectorised over any leading shape).

Frame (docs/design.md): metres, x to the right (body midline x = 0), y forward. The left
shoulder is fixed at SHOULDER. Angles in degrees as in the paper's released agent:
``shoulder`` is the absolute angle of the upper arm from +x, ``elbow`` the angle of the
forearm relative to the upper arm. The resting hand is at REST_HAND with the elbow
pointing outward (to the left), which is the ``elbow < 0`` branch of the inverse.

Example::

    x, y = forward(*REST_POSE)          # (-0.30, 0.50)
    shoulder, elbow = inverse(-0.45, 0.50)
"""
from __future__ import annotations

import numpy as np

from ..component import ComponentError

SHOULDER = (-0.20, 0.0)     # m, left shoulder joint (fixed on the torso)
UPPER_ARM = 0.3595          # m, shoulder -> elbow
FOREARM = 0.3694            # m, elbow -> hand
REST_HAND = (-0.30, 0.50)   # m, resting hand position

_REACH_MAX = UPPER_ARM + FOREARM
_REACH_MIN = abs(UPPER_ARM - FOREARM)


def forward(shoulder_deg, elbow_deg):
    """Hand position (x, y) in m for joint angles in degrees (broadcast together)."""
    shoulder = np.radians(np.asarray(shoulder_deg, dtype=np.float64))
    forearm = shoulder + np.radians(np.asarray(elbow_deg, dtype=np.float64))
    x = SHOULDER[0] + UPPER_ARM * np.cos(shoulder) + FOREARM * np.cos(forearm)
    y = SHOULDER[1] + UPPER_ARM * np.sin(shoulder) + FOREARM * np.sin(forearm)
    return x, y


def inverse(x, y):
    """Joint angles (shoulder, elbow) in degrees that put the hand at (x, y) m.

    Elbow-outward branch (elbow in [-180, 0]), the branch of the resting pose. The
    shoulder angle is returned in [-90, 270) so that it is continuous over the table
    (the arm never points straight back, -90 deg). Raises ComponentError (a ValueError)
    naming the first hand position outside the reachable annulus.
    """
    x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    dx, dy = x - SHOULDER[0], y - SHOULDER[1]
    distance = np.hypot(dx, dy)
    bad = ~((distance <= _REACH_MAX) & (distance >= _REACH_MIN))  # also catches NaN
    if np.any(bad):
        index = tuple(np.argwhere(bad)[0]) if bad.ndim else ()
        raise ComponentError(
            f"hand position (x, y) = ({x[index]:.4g}, {y[index]:.4g}) m is out of reach: its distance "
            f"{distance[index]:.4g} m from the shoulder is outside [{_REACH_MIN:.4g}, {_REACH_MAX:.4g}] m")
    cos_elbow = (distance**2 - UPPER_ARM**2 - FOREARM**2) / (2 * UPPER_ARM * FOREARM)
    elbow = -np.arccos(np.clip(cos_elbow, -1.0, 1.0))
    shoulder = np.arctan2(dy, dx) - np.arctan2(FOREARM * np.sin(elbow), UPPER_ARM + FOREARM * np.cos(elbow))
    shoulder_deg = (np.degrees(shoulder) + 90.0) % 360.0 - 90.0
    return shoulder_deg, np.degrees(elbow)


def jacobian(shoulder_deg, elbow_deg):
    """d(hand x, y) / d(shoulder, elbow) in m/deg, shape (..., 2, 2): rows x, y; columns angles."""
    shoulder = np.radians(np.asarray(shoulder_deg, dtype=np.float64))
    forearm = shoulder + np.radians(np.asarray(elbow_deg, dtype=np.float64))
    per_degree = np.pi / 180.0
    dx_delbow = -FOREARM * np.sin(forearm) * per_degree
    dy_delbow = FOREARM * np.cos(forearm) * per_degree
    dx_dshoulder = -UPPER_ARM * np.sin(shoulder) * per_degree + dx_delbow
    dy_dshoulder = UPPER_ARM * np.cos(shoulder) * per_degree + dy_delbow
    return np.stack([np.stack([dx_dshoulder, dx_delbow], -1), np.stack([dy_dshoulder, dy_delbow], -1)], -2)


REST_POSE = tuple(float(angle) for angle in inverse(*REST_HAND))  # deg, about (147.7, -91.2)
