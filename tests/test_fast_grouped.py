"""The fast decoder's products per point batched by the number of trials a point holds
(rhi.components.vision.fast.grouped_point_products) against one product per point (point_products).

Truth: float64 sums in numpy, within Higham's bound for a float32 sum of P terms, |fl(sum) - sum| <= gamma_P sum|x|,
gamma_P = P u / (1 - P u), u = 2^-24; and the decoder with the grouped products turned off, to the bit.
"""
import numpy as np
import pytest
import torch

from rhi.components.body import kinematics
from rhi.components.vision import fast
from rhi.components.vision.fast import LinearisedDecoder, grouped_point_products, point_products
from tests.test_batching import tiny_model
from tests.test_fast import start

PIXELS = 32 * 32


def slots_of_every_shape(rng):
    """60 trials on points holding 1 to 7 trials, some as runs of neighbouring trials, some scattered."""
    sizes = [1] * 12 + [2] * 4 + [3] * 3 + [5, 7, 7]
    slots = np.repeat(rng.choice(40, size=len(sizes), replace=False), sizes)
    scattered = rng.permutation(len(slots))[:30]
    slots[scattered] = slots[np.sort(scattered)]  # half the trials shuffled among themselves
    return slots


@pytest.mark.parametrize("seed", range(3))
def test_both_products_are_the_float64_products_within_highams_bound(seed):
    rng = np.random.default_rng(seed)
    slots = slots_of_every_shape(rng)
    store = torch.from_numpy(rng.normal(0, 1, (40, 3, PIXELS)).astype(np.float32))
    sensed = torch.from_numpy(rng.uniform(0, 1, (len(slots), PIXELS)).astype(np.float32))
    residual64 = sensed.double().numpy() - store[slots, 0].double().numpy()
    terms = residual64[:, None, :] * store[slots, 1:].double().numpy()
    gamma = PIXELS * 2.0**-24 / (1 - PIXELS * 2.0**-24)
    for products in (point_products, grouped_point_products):
        projected, squared = products(sensed, store, slots, torch.empty(len(slots), PIXELS))
        # the residual is rounded to float32 first (u |r| per pixel), then the sum: 2 gamma_P on sum|x|
        assert (np.abs(projected.numpy() - terms.sum(2)) <= 2 * gamma * np.abs(terms).sum(2)).all()
        assert (np.abs(squared.numpy() - (residual64**2).sum(1)) <= 3 * gamma * (residual64**2).sum(1)).all()


def batch_run(grouped: bool, steps=12, trials=24):
    """A fit-like batch on the tiny decoder: every trial's belief wanders on its own, so its points are shared by
    1 to many trials in the course of the run; the visual terms of every step."""
    rng = np.random.default_rng(5)
    rest = np.array(kinematics.REST_POSE)
    image = rng.uniform(0, 1, (trials, 32, 32)).astype(np.float32)
    decoder = LinearisedDecoder(tiny_model(), threads=1, fast_layout=False)
    decoder.grouped_products = grouped
    mu = np.broadcast_to(rest, (trials, 2)).copy()
    start(decoder, trials, mu, image, relinearise_tolerance=0.05)
    out, shapes = [], set()
    for step in range(1, steps + 1):
        mu = mu + rng.choice([0.0, 0.0, 0.03, 0.08], size=(trials, 1)) * rng.choice([-1, 1], size=(trials, 2))
        decoder.set("mu", mu)
        decoder.do_step(0.02 * step, 0.02)
        shapes |= set(np.unique(np.unique(decoder._slots, return_counts=True)[1]).tolist())
        out.append([decoder.values[name].copy() for name in ("visual_drive", "visual_error", "visual_stiffness")])
    return decoder, out, shapes


def test_the_decoder_with_grouped_products_gives_the_bits_of_one_product_per_point():
    grouped, with_groups, shapes = batch_run(True)
    alone, without, _ = batch_run(False)
    assert len(shapes) >= 4 and 1 in shapes  # points of one trial and of several, several sizes
    assert all(np.array_equal(a, b) for step_a, step_b in zip(with_groups, without) for a, b in zip(step_a, step_b))
    assert alone.grouped_products is False
    # where this CPU's matrix library computes a batch's products as it computes each alone (checked here
    # directly), the decoder kept the grouped products
    rng = np.random.default_rng(0)
    store = torch.from_numpy(rng.normal(0, 1, (40, 3, PIXELS)).astype(np.float32))
    slots = slots_of_every_shape(rng)
    sensed = torch.from_numpy(rng.uniform(0, 1, (len(slots), PIXELS)).astype(np.float32))
    room = torch.empty(len(slots), PIXELS)
    alike = all(torch.equal(a, b) for a, b in zip(point_products(sensed, store, slots, room),
                                                   grouped_point_products(sensed, store, slots, room)))
    assert grouped.grouped_products is alike


def test_a_grouped_product_that_differs_turns_them_off_and_the_bits_stay(monkeypatch):
    alone, without, _ = batch_run(False)
    real = fast.grouped_point_products

    def off_by_an_ulp(sensed, store, slots, residual):
        projected, squared = real(sensed, store, slots, residual)
        if len(np.unique(slots)) < len(slots):  # once some point holds two trials
            squared[-1] = torch.nextafter(squared[-1], torch.tensor(np.inf))
        return projected, squared

    monkeypatch.setattr(fast, "grouped_point_products", off_by_an_ulp)
    decoder, with_groups, _ = batch_run(True)
    assert decoder.grouped_products is False
    assert all(np.array_equal(a, b) for step_a, step_b in zip(with_groups, without) for a, b in zip(step_a, step_b))
