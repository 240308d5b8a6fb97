"""The fast (linearised) decoder: g(mu) replaced by its tangent at a nearby linearisation point.

Each trial keeps a linearisation point mu0, with g0 = g(mu0) and J0 = dg/dmu(mu0) from
forward-mode JVPs (:meth:`GenerativeModel.predict_with_jacobian`), and the decoder predicts

    g(mu) ~ g0 + J0 (mu - mu0),   J(mu) ~ J0.

When mu moves more than ``relinearise_tolerance`` (deg, on either joint) from mu0, the trial
takes a new point: the nearest stored point within the tolerance of its mu if there is
one, else mu itself; either way |mu - mu0| <= tolerance after every step. Points are
shared between trials and kept (up to ``memory_mb``, the least recently used dropped
first), so trials moving along similar paths (the protocol's repetitions of a cell) share
decoder evaluations, several times fewer than each trial alone would need, and all new
points of a step are evaluated in one batched call. Tolerance 0 takes a new point every
step mu changes: the outputs are then the exact decoder's (to float rounding).

A step costs one pass over each trial's image and one over each point in use, for
J0^T (s - g0) and |s - g0|^2 per trial; the terms in d = mu - mu0 follow in float64
(:func:`linearised_terms`), scaled by the precision as in :func:`visual_drive` and
:func:`visual_error`.
The prediction output is computed only if read (:class:`~rhi.components.component.Deferred`).

Example::

    decoder = LinearisedDecoder("conv.pt", relinearise_tolerance=0.005)
    ...simulate as with Decoder...; decoder.decoder_points   # linearisations the decoder evaluated
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from ..component import Deferred
from ..variables import Variable
from .component import Decoder, jacobian_gram, largest_eigenvalue, visual_error
from .optimised import optimised

DEFAULT_TOLERANCE = 0.005  # deg: every cell's final drift within 1 % of the exact integrator's (docs/decoders.md, "Fast mode")


def linearised_terms(projected, squared, gram, step):
    """J^T e (B, 2) and |e|^2 (B,) of eqs. 4 and 6 (before the precision) for g(mu) ~ g0 + J0 d, J ~ J0.

    With e = s_v - g0 - J0 d and d = mu - mu0 (B, 2), from projected = J0^T (s_v - g0) (B, 2),
    squared = |s_v - g0|^2 (B,) and gram = J0^T J0 (B, 2, 2), all float64:
    J0^T e = projected - gram d and |e|^2 = squared - 2 d . projected + d^T gram d (>= 0 but for rounding).
    """
    drive = projected - (gram @ step[:, :, None])[:, :, 0]
    error = squared - 2 * (projected * step).sum(1) + (step[:, None] @ gram @ step[:, :, None]).view(-1)
    return drive, error.clamp(min=0)


def nearest_within(points, slots, targets, tolerance):
    """For each target, the nearest of ``points`` in the max-norm if it lies within that target's tolerance.

    The same choice as taking the argmin of max|point - target| over all points in ``slots`` order (the first of
    equal distances: the smallest slot) and keeping it where the distance is <= the tolerance, without
    comparing every target with every point: only the points whose first coordinate lies within the tolerance
    (found by a sort on it, the window widened by a relative 1e-9 so that rounding cannot leave one out) have
    their distance computed, exactly as the full comparison would.

    Parameters
    ----------
    points : ndarray, (N, 2)
        The stored points, deg, in the order of ``slots``.
    slots : ndarray, (N,) int
        Their slots, ascending.
    targets : ndarray, (M, 2)
        deg.
    tolerance : ndarray, (M,)
        deg, >= 0.

    Returns
    -------
    nearest : ndarray, (M,) int
        The slot of each target's nearest point within its tolerance; 0 where there is none.
    distance : ndarray, (M,)
        Its max-norm distance, deg; inf where there is none.
    """
    nearest, distance = np.zeros(len(targets), dtype=np.int64), np.full(len(targets), np.inf)
    if not len(points) or not len(targets):
        return nearest, distance
    order = np.argsort(points[:, 0], kind="stable")
    first = points[order, 0]
    reach = tolerance * (1 + 1e-9) + 1e-300
    low = np.searchsorted(first, targets[:, 0] - reach, side="left")
    high = np.searchsorted(first, targets[:, 0] + reach, side="right")
    counts = high - low
    if not counts.sum():
        return nearest, distance
    target = np.repeat(np.arange(len(targets)), counts)  # one (target, candidate) pair a row
    starts = np.repeat(low - np.cumsum(counts) + counts, counts)
    candidate = order[np.arange(counts.sum()) + starts]
    gap = np.abs(points[candidate] - targets[target]).max(axis=1)
    keep = gap <= tolerance[target]
    target, candidate, gap = target[keep], candidate[keep], gap[keep]
    best = np.lexsort((candidate, gap, target))  # per target: the smallest gap, then the first in slot order
    target, candidate, gap = target[best], candidate[best], gap[best]
    head = np.ones(len(target), dtype=bool)
    head[1:] = target[1:] != target[:-1]
    nearest[target[head]], distance[target[head]] = slots[candidate[head]], gap[head]
    return nearest, distance


def point_products(sensed, store, slots, residual):
    """J0^T (s - g0) (B, 2) and |s - g0|^2 (B,) of each trial at its point, one pass over each point in use.

    Parameters
    ----------
    sensed : Tensor, (B, P) float32
        Each trial's image.
    store : Tensor, (N, 3, P) float32
        Per stored point: g0, then J0's two columns.
    slots : ndarray, (B,) int
        Each trial's point in ``store``.
    residual : Tensor, (>= B, P) float32
        Room for s - g0 (preallocated: a fresh 16 MB a step costs page faults).

    Returns
    -------
    projected : Tensor, (B, 2) float32
    squared : Tensor, (B,) float32
    """
    batch = len(slots)
    projected, squared = torch.empty(batch, 2), torch.empty(batch)
    for slot in np.unique(slots):
        trials = np.flatnonzero(slots == slot)
        rows = residual[:len(trials)]
        if trials[-1] - trials[0] == len(trials) - 1:  # a run of trials: no gather, results by slice
            part = slice(trials[0], trials[-1] + 1)
            torch.sub(sensed[part], store[slot, 0], out=rows)
            projected[part] = F.linear(rows, store[slot, 1:])
            squared[part] = torch.linalg.vector_norm(rows, dim=1).square()
        else:  # the same numbers, copied by index (torch's numpy-index assignment costs more)
            index = torch.from_numpy(trials)
            torch.index_select(sensed, 0, index, out=rows).sub_(store[slot, 0])
            projected.index_copy_(0, index, F.linear(rows, store[slot, 1:]))
            squared.index_copy_(0, index, torch.linalg.vector_norm(rows, dim=1).square())
    return projected, squared


def grouped_point_products(sensed, store, slots, residual):
    """:func:`point_products` with the points that hold the same number of trials k in one batched product:
    ``torch.bmm`` of (G, k, P) residuals by the G points' (G, P, 2) Jacobians, one call per group size k in use
    instead of one per point (a fit's batch of 300 trials stands on about 100 points a step, two thirds of them
    holding one trial). Each of bmm's G products is the (k, P) x (P, 2) matrix product F.linear makes of that point's
    trials, rows in the same order, so the bits are those of :func:`point_products` where the CPU's matrix library
    computes a product of a batch as it computes it alone; :class:`LinearisedDecoder` checks that on each group size
    it meets. The residuals are gathered once, group after group, and their squared norms taken in one call (a fit's
    batch of 400 distinct participants stands on points of about 15 sizes a step). Parameters and returns as
    :func:`point_products`.
    """
    batch, pixels = sensed.shape
    order = np.argsort(slots, kind="stable")  # the trials of a point together, in their own order
    ordered = slots[order]
    starts = np.flatnonzero(np.concatenate(([True], ordered[1:] != ordered[:-1])))
    counts = np.diff(np.append(starts, batch))
    # The points by their number of trials (then by slot), each point's trials together: one gather of every
    # residual, one norm and one copy back, and per number k only the subtraction and the batched product.
    by_size = np.argsort(counts, kind="stable")
    sizes = counts[by_size]
    offsets = np.cumsum(sizes) - sizes  # each point's first row among the gathered residuals
    within = np.arange(batch) - np.repeat(offsets, sizes)
    index = torch.from_numpy(order[np.repeat(starts[by_size], sizes) + within])
    points = torch.from_numpy(ordered[starts[by_size]])
    rows = torch.index_select(sensed, 0, index, out=residual[:batch])
    products = torch.empty(batch, 2)
    size_values, first_points, groups = np.unique(sizes, return_index=True, return_counts=True)
    for size, first, count in zip(size_values.tolist(), first_points.tolist(), groups.tolist()):
        row = int(offsets[first])
        block, these = rows[row:row + count * size].view(count, size, pixels), points[first:first + count]
        block.sub_(store[these, 0][:, None, :])
        torch.bmm(block, store[these, 1:].transpose(1, 2), out=products[row:row + count * size].view(count, size, 2))
    projected, squared = torch.empty(batch, 2), torch.empty(batch)
    projected.index_copy_(0, index, products)
    squared.index_copy_(0, index, torch.linalg.vector_norm(rows, dim=1).square())
    return projected, squared


class LinearisedDecoder(Decoder):
    """Decoder component with the tangent-linear fast mode; same variables plus relinearise_tolerance.

    checkpoint, name, resolution, rest_pose, half_ranges, threads: as for Decoder.
    relinearise_tolerance: start value of the parameter (deg, >= 0).
    fast_layout: run the decoder through :func:`optimised` (written-out JVPs, channels-last), on a CPU.
    memory_mb: room for stored linearisations (12 bytes a pixel each); at least 2 per trial.
    device: where the decoder runs (as for Decoder); the stored linearisations stay on the CPU.

    After a run: ``relinearisations`` (B,) counts how often each trial's linearisation point
    changed (the first included); ``call_sizes`` lists the points of each batched decoder call; ``grouped_products``
    says whether the products per point stayed batched by the number of trials at a point (:meth:`_products`).
    """

    def __init__(self, checkpoint, name: str = "decoder", relinearise_tolerance: float = DEFAULT_TOLERANCE,
                 resolution: int | None = None, rest_pose=None, half_ranges=None, threads: int | None = None,
                 fast_layout: bool = True, memory_mb: float = 256.0, device: str = "cpu"):
        super().__init__(checkpoint, name, resolution, rest_pose, half_ranges, threads, device)
        if fast_layout and self.model.device.type == "cpu":  # the optimised copy is for CPUs
            self.model = optimised(self.model)
        tolerance = Variable("relinearise_tolerance", "parameter", start=relinearise_tolerance, unit="deg", min=0.0,
                             description="take a new linearisation point when a joint of mu moves more than this from mu0")
        self.variables[tolerance.name] = tolerance
        self.memory_mb = memory_mb
        self.relinearisations = np.zeros(0, dtype=np.int64)
        self.call_sizes: list[int] = []
        self.grouped_products = True  # False once a grouped product differed from a point's own (_products)

    @property
    def decoder_points(self) -> int:
        """Linearisation points the decoder evaluated."""
        return sum(self.call_sizes)

    @property
    def decoder_calls(self) -> int:
        """Batched decoder calls made (the ``i``-th evaluated ``call_sizes[i]`` points)."""
        return len(self.call_sizes)

    def initialize(self):
        """Empty the store of linearisation points (room for ``memory_mb``, at least 2 per trial) and the counters,
        then publish as :meth:`Decoder.initialize`.
        """
        pixels = self.model.resolution ** 2
        capacity = max(2 * self.batch_size, int(self.memory_mb * 2**20) // (12 * pixels))
        self._store = torch.empty(capacity, 3, pixels)  # per point: g0, then J0's columns (shoulder, elbow)
        self._gram = torch.empty(capacity, 2, 2, dtype=torch.float64)  # J0^T J0
        self._points = np.full((capacity, 2), np.nan)    # deg; NaN: an empty slot
        self._last_used = np.full(capacity, -1)          # step count, for least-recently-used eviction
        self._slots = np.full(self.batch_size, -1)       # each trial's point; -1: none yet
        self._residual = torch.empty(self.batch_size, pixels)  # s - g0 of the trials at a point
        self._checked_sizes = np.zeros(0, dtype=np.int64)  # numbers of trials at a point whose products were checked
        self._steps = 0
        self.relinearisations = np.zeros(self.batch_size, dtype=np.int64)
        self.call_sizes = []
        super().initialize()

    def stale(self, mu: np.ndarray) -> np.ndarray:
        """Trials (B,) bool that have no point yet or whose belief moved more than the tolerance from it."""
        moved = np.abs(mu - self._points[self._slots]).max(axis=1)
        return (self._slots < 0) | ~(moved <= self.values["relinearise_tolerance"])

    def reassign(self, trials: np.ndarray, mu: np.ndarray) -> None:
        """A new point for each of ``trials``: the nearest stored (or just chosen) point within its tolerance of its
        mu, else its mu itself; the new points are evaluated in one decoder call."""
        tolerance = self.values["relinearise_tolerance"]
        stored = np.flatnonzero(~np.isnan(self._points[:, 0]))
        # The nearest stored point within its tolerance of every trial at once (distance inf where there is none:
        # a farther stored point could never be taken, and a new point nearer than it is nearer than inf too),
        # then, trial by trial, the nearest of this call's new points: the stored one wins a tie, as the first of
        # one list, stored then new, would.
        nearest, distance = nearest_within(self._points[stored], stored, mu[trials], tolerance[trials])
        new = np.empty((len(trials), 2))  # this call's new points; the k-th has slot -1 - k until evaluated
        count = 0
        for trial, slot, gap in zip(trials, nearest, distance):
            if count:
                new_gap = np.abs(new[:count] - mu[trial]).max(axis=1)
                closest = int(new_gap.argmin())
                if new_gap[closest] < gap:
                    slot, gap = -1 - closest, new_gap[closest]
            if np.isfinite(gap) and gap <= tolerance[trial]:
                self._slots[trial] = slot
            else:
                self._slots[trial] = -1 - count
                new[count] = mu[trial]
                count += 1
        new = new[:count]
        if count:
            keep = self._slots[self._slots >= 0]
            slots = self.linearise(new, keep)
            pending = self._slots < 0
            self._slots[pending] = slots[-1 - self._slots[pending]]
        self.relinearisations[trials] += 1

    def linearise(self, points: np.ndarray, keep: np.ndarray) -> np.ndarray:
        """g0, J0 and J0^T J0 at ``points`` (N, 2) in one decoder call, into slots other than ``keep``."""
        free = np.flatnonzero(np.isnan(self._points[:, 0]))
        if len(free) < len(points):  # evict the least recently used points that no trial stands on now
            spare = np.setdiff1d(np.flatnonzero(~np.isnan(self._points[:, 0])), keep)
            free = np.concatenate([free, spare[np.argsort(self._last_used[spare], kind="stable")]])
        slots = free[:len(points)]
        with torch.no_grad():
            prediction, jacobian = self.model.predict_with_jacobian(torch.from_numpy(points.astype(np.float32)))
            prediction, jacobian = prediction.cpu(), jacobian.cpu()  # the store is on the CPU (no copy there)
        index = torch.from_numpy(slots)
        self._store[index, 0] = prediction.reshape(len(points), -1)
        self._store[index, 1:] = jacobian.reshape(len(points), 2, -1)
        self._gram[index] = jacobian_gram(jacobian).double()
        self._points[slots] = points
        self.call_sizes.append(len(points))
        return slots

    def _update(self):
        mu, image, precision = self._checked_inputs()
        batch, side = image.shape[0], image.shape[1]
        self._steps += 1
        stale = np.flatnonzero(self.stale(mu))
        if len(stale):
            self.reassign(stale, mu)
        slots = self._slots
        self._last_used[slots] = self._steps

        sensed = torch.from_numpy(image).view(batch, -1)
        with torch.no_grad():
            projected, squared = self._products(sensed, slots)
        step = mu - self._points[slots]  # d, float64
        gram = self._gram[torch.from_numpy(slots)]
        drive, error = linearised_terms(projected.double(), squared.double(), gram, torch.from_numpy(step))
        weight = precision.double()
        self.values["visual_drive"] = (drive * weight[:, None]).numpy()
        self.values["visual_error"] = visual_error(error, weight).numpy()
        self.values["visual_stiffness"] = largest_eigenvalue(gram * weight[:, None, None]).numpy()
        self.values["prediction"] = Deferred(self._prediction_of(slots, step, side))

    def _products(self, sensed, slots):
        """:func:`grouped_point_products`, checked against :func:`point_products` bit for bit at each step that
        brings a number of trials at one point not met before; at the first difference this decoder keeps to
        :func:`point_products`."""
        if not self.grouped_products:
            return point_products(sensed, self._store, slots, self._residual)
        products = grouped_point_products(sensed, self._store, slots, self._residual)
        points, counts = np.unique(slots, return_counts=True)
        new = ~np.isin(counts, self._checked_sizes)
        if new.any():  # the points of sizes not met before, alone (a point's numbers do not depend on the others)
            trials = np.flatnonzero(np.isin(slots, points[new]))
            alone = point_products(sensed[trials], self._store, slots[trials], self._residual)
            if not all(torch.equal(mine[trials], theirs) for mine, theirs in zip(products, alone)):
                self.grouped_products = False
                return point_products(sensed, self._store, slots, self._residual)
            self._checked_sizes = np.union1d(self._checked_sizes, counts[new])
        return products

    def _prediction_of(self, slots: np.ndarray, step: np.ndarray, side: int):
        """g0 + J0 d per trial (B, side, side) float32, for the points and steps of this step."""
        store, slots, step = self._store, torch.from_numpy(slots.copy()), torch.from_numpy(step.astype(np.float32))

        def compute():  # the store is unchanged until the next step, which replaces this output
            rows = store[slots]
            # A trial on its point exactly (d = 0) predicts g0 to the bit.
            return torch.baddbmm(rows[:, :1], step[:, None], rows[:, 1:]).view(-1, side, side).numpy()
        return compute
