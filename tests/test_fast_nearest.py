"""The fast decoder's search for a stored linearisation point (rhi.components.vision.fast.nearest_within) against the
comparison of every target with every point that it replaces: the same slot and distance wherever the nearest point
lies within the tolerance, none elsewhere. Truth: numpy's argmin over the full table of max-norm distances (the
first of equal distances), written out here."""
import numpy as np
import pytest

from rhi.components.vision.fast import nearest_within


def brute_force(points, slots, targets, tolerance):
    gap = np.abs(points[None] - targets[:, None]).max(axis=2)
    closest = gap.argmin(axis=1)
    distance = gap[np.arange(len(targets)), closest]
    within = distance <= tolerance
    return np.where(within, slots[closest], 0), np.where(within, distance, np.inf)


@pytest.mark.parametrize("seed", range(5))
def test_the_window_search_is_the_full_comparison(seed):
    rng = np.random.default_rng(seed)
    # points on a coarse grid (many equal distances, exact ties) and scattered ones, targets near and far
    grid = rng.integers(0, 40, size=(300, 2)) * 0.005 + 140.0
    scattered = 140.0 + rng.uniform(0, 0.2, size=(300, 2))
    points = np.concatenate([grid, scattered, grid[:50]])  # repeated points: the smaller slot must win
    slots = np.sort(rng.choice(5000, size=len(points), replace=False))
    targets = np.concatenate([grid[rng.integers(0, 300, 100)] + rng.choice([-0.005, 0.0, 0.005], size=(100, 2)),
                              140.0 + rng.uniform(-0.05, 0.25, size=(200, 2))])
    tolerance = rng.choice([0.0, 0.002, 0.005, 0.01], size=len(targets))
    got = nearest_within(points, slots, targets, tolerance)
    want = brute_force(points, slots, targets, tolerance)
    assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
    assert np.isfinite(want[1]).sum() > 100  # the check meets many points within their tolerance, ties among them


def test_no_points_or_no_targets_find_nothing():
    nearest, distance = nearest_within(np.empty((0, 2)), np.empty(0, int), np.ones((3, 2)), np.full(3, 0.005))
    assert nearest.tolist() == [0, 0, 0] and np.isinf(distance).all()
    assert nearest_within(np.ones((2, 2)), np.arange(2), np.empty((0, 2)), np.empty(0))[0].size == 0
