"""The adopted point of a fit (rhi.master.fit.point): the posterior sample of highest density in the flow's own space,
and the inference-space density beside it, checked against the change of variables worked by hand."""
import math

import numpy as np
import pytest
import torch

from rhi.master.fit import inference, point
from rhi.master.fit.plan import Parameter

PARAMETERS = [Parameter("x.a", "uniform", 0.0, 1.0), Parameter("x.b", "log-uniform", 0.1, 10.0)]


class StandardNormalFlow:
    """A stand-in posterior: standard normal in the flow's space around the statistics, whatever they are."""

    def __init__(self, space: str):
        self.prior = inference.flow_prior(PARAMETERS, {"space": space})
        self.statistics_scale = lambda x: np.asarray(x, dtype=float)

    def log_prob(self, z, x, norm_posterior):
        assert norm_posterior is False  # a constant left out: the mode does not depend on it
        return torch.distributions.Normal(x[0], 1.0).log_prob(z).sum(-1)


def log_phi(z: float) -> float:
    return -0.5 * math.log(2 * math.pi) - 0.5 * z * z


def by_hand(a: float, log_b: float) -> float:
    """log q in the inference space (a, ln b): each coordinate's logit onto the line, z = logit(u) with
    u = (theta - low)/(high - low), dz/dtheta = 1/((high - low) u (1 - u)); q_theta = phi(z) dz/dtheta."""
    total = 0.0
    for theta, low, high in ((a, 0.0, 1.0), (log_b, math.log(0.1), math.log(10.0))):
        u = (theta - low) / (high - low)
        total += log_phi(math.log(u / (1 - u))) - math.log((high - low) * u * (1 - u))
    return total


def test_the_inference_space_density_is_the_flow_density_times_the_jacobian():
    samples = np.array([[0.3, 0.0], [0.5, 1.0], [0.9, -2.0]])
    got = point.inference_log_density(StandardNormalFlow("unconstrained"), np.zeros(2), samples)
    # float32 in the flow: relative 1e-6 of values of order 1, the logit near the bounds 1e-5 (-2 is 0.3 from ln 0.1)
    assert got == pytest.approx([by_hand(*row) for row in samples], abs=1e-4)


def test_a_bounded_flow_is_its_own_inference_space():
    samples = np.array([[0.3, 0.0], [0.5, 1.0]])
    got = point.inference_log_density(StandardNormalFlow("bounded"), np.zeros(2), samples)
    want = [log_phi(a) + log_phi(b) for a, b in samples]
    assert got == pytest.approx(want, abs=1e-6)  # float32 of numbers of order 1


def test_the_highest_density_draw_skips_non_finite_values_and_takes_the_first_of_ties():
    assert point.highest_density_draw([-3.0, float("nan"), -1.0, -1.0, float("-inf")]) == 2
    with pytest.raises(ValueError):
        point.highest_density_draw([float("nan"), float("-inf")])


def flow_by_hand(a: float, log_b: float) -> float:
    """log q in the flow's space: each coordinate's logit, z = logit(u), under the stand-in's standard normal."""
    return sum(log_phi(math.log(u / (1 - u))) for u in (a, (log_b - math.log(0.1)) / (math.log(10.0) - math.log(0.1))))


def test_the_point_is_the_mode_among_the_samples_in_the_flows_space_in_the_parameters_units():
    samples = np.array([[[0.3, 0.0], [0.5, 0.0], [0.9, -2.0]]])
    densities = [flow_by_hand(*row) for row in samples[0]]
    assert int(np.argmax(densities)) == 1  # by hand, the middle sample (the centre of both supports)
    text = point.point_csv(PARAMETERS, ["p"], StandardNormalFlow("unconstrained"), np.zeros((1, 2)), samples)
    lines = text.strip().splitlines()
    assert lines[0] == ",".join(point.POINT_COLUMNS)
    rows = [line.split(",") for line in lines[1:]]
    assert [r[1] for r in rows] == ["x.a", "x.b"]
    assert float(rows[0][2]) == pytest.approx(0.5) and float(rows[1][2]) == pytest.approx(1.0)  # e^0: its own unit
    assert rows[0][3] == rows[1][3] == "1"
    assert float(rows[0][4]) == pytest.approx(densities[1], abs=1e-5)  # float32 of numbers of order 1


class CauchyFlow(StandardNormalFlow):
    """A stand-in whose tails are too heavy (a Cauchy in the flow's space): the error an estimator makes far out."""

    def log_prob(self, z, x, norm_posterior):
        return torch.distributions.Cauchy(x[0], 1.0).log_prob(z).sum(-1)


def test_a_flows_heavy_tail_puts_the_inference_space_mode_at_the_edge_and_the_rule_keeps_the_bulk():
    """Why the rule takes the flow's own space: the inference-space density is the flow's times 1/(u (1 - u)), which
    at u = 0.999 multiplies it by about 1000, more than a Cauchy tail loses there (logit 0.999 = 6.9: by hand,
    log q_z falls from -log(pi) to -log(pi (1 + 6.9^2)), 3.89 nats, while the Jacobian gains 6.91 - log 4 = 5.52)."""
    samples = np.array([[0.5, 0.0], [0.999, 0.0]])
    flow = CauchyFlow("unconstrained")
    inference = point.inference_log_density(flow, np.zeros(2), samples)
    own = point.flow_log_density(flow, np.zeros(2), samples)
    by_hand_gain = -math.log(1 + math.log(999) ** 2) - math.log(0.999 * 0.001) - math.log(4)  # Cauchy, Jacobians
    assert inference[1] - inference[0] == pytest.approx(by_hand_gain, abs=1e-3)  # float32 near the bound: about 1e-4
    assert point.highest_density_draw(inference) == 1 and point.highest_density_draw(own) == 0
    text = point.point_csv(PARAMETERS, ["p"], flow, np.zeros((1, 2)), samples[None])
    assert float(text.strip().splitlines()[1].split(",")[2]) == pytest.approx(0.5)
