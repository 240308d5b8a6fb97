"""A fit's adopted point: one joint draw of the posterior, not the marginal medians.

The marginal medians of a curved posterior need not be a point of it at all (each median is taken alone), and a
model run at them need not reproduce what the posterior predicts. The rule here, fixed before any result it
chooses is seen: of a participant's posterior samples (``fit.posterior_samples``, those posterior.csv holds), the
one of highest posterior density under the trained estimator in the *flow's own space* (the unconstrained space of
``fit.estimator.space = "unconstrained"``, the inference space of a bounded flow): the density the flow was trained
to give, with no change of variables. It uses the training data alone (the participant's statistics), nothing
judged after.

Why not the density in the inference space (the rule of the first population fits): that density is the flow's
times the Jacobian of the unconstraining map, which diverges at a bounded prior's edges, so wherever the flow's
tails are not exact a sample at an edge outranks the bulk; in the population fits of the ownership model the
inference-space mode lay at or beyond its own marginal 90 % interval, at the prior's edge, in one or more
parameters of every fit (docs/fit.md, "Several studies"). :func:`inference_log_density` remains, as that
diagnostic.

point.csv: per participant and parameter, the point's value in the parameter's unit, which sample it is, and its
log density.
"""
from __future__ import annotations

import numpy as np

from rhi.master.outputs.tables import csv_text, number

# column -> meaning, for docs/fit.md
POINT_COLUMNS = {"participant": "the participant's label", "parameter": "the fitted parameter's key",
                 "value": "the adopted point: the posterior sample of highest posterior density (in the flow's own "
                          "space), in the key's unit",
                 "sample": "its index among the participant's posterior samples (posterior.csv's order)",
                 "log_density": "the estimator's log posterior density there, in the flow's own space"}


def highest_density_draw(log_density: np.ndarray) -> int:
    """The index of the largest finite log density (the first of ties); ValueError if none is finite.

    The mode of a posterior known through samples and a density: argmax_i log q(theta_i | x)."""
    values = np.asarray(log_density, dtype=float)
    finite = np.isfinite(values)
    if not finite.any():
        raise ValueError("no posterior sample has a finite log density")
    return int(np.argmax(np.where(finite, values, -np.inf)))


def inference_log_density(posterior_, observed: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """log q(theta | x) of each sample in the inference space: the flow's log density at T(theta) plus
    log |det dT/dtheta|, T the map from the inference space to the flow's (the unconstraining bijection,
    ``rhi.master.fit.inference.unconstraining``; the identity for ``space = "bounded"``). Change of variables:
    q_theta(theta) = q_z(T(theta)) |det T'(theta)|.

    posterior_ : a posterior of :func:`rhi.master.fit.inference.posterior` (its ``prior`` and
        ``statistics_scale``); observed : (statistics,) the participant's statistics, their own units;
    samples : (L, parameters) in the inference space (:func:`rhi.master.fit.inference.sample`'s)."""
    flow, jacobian = log_densities(posterior_, observed, samples)
    return flow + jacobian


def flow_log_density(posterior_, observed: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """log q(z | x) of each sample in the flow's own space, z = T(theta): the density the estimator was trained to
    give (:func:`inference_log_density` without its Jacobian term; the arguments the same)."""
    return log_densities(posterior_, observed, samples)[0]


def log_densities(posterior_, observed: np.ndarray, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(log q(z | x), log |det dz/dtheta|) of each sample, float64 of the flow's float32."""
    import torch

    theta = torch.as_tensor(np.asarray(samples, dtype=float), dtype=torch.float32)
    scaled = torch.as_tensor(posterior_.statistics_scale(np.asarray(observed, dtype=float)[None]), dtype=torch.float32)
    prior = posterior_.prior
    if isinstance(prior, torch.distributions.TransformedDistribution):
        transform = torch.distributions.transforms.ComposeTransform(prior.transforms)
        z = transform(theta)
        jacobian = transform.log_abs_det_jacobian(theta, z)
    else:
        z, jacobian = theta, torch.zeros(len(theta))
    with torch.no_grad():
        flow = posterior_.log_prob(z, x=scaled, norm_posterior=False)  # the normalisation is one constant
    return flow.double().numpy(), jacobian.double().numpy()


def point_csv(parameters: list, participants: list[str], posterior_, observed: np.ndarray,
              samples: np.ndarray) -> str:
    """point.csv (POINT_COLUMNS): each participant's adopted point by this module's rule.

    observed : (participants, statistics); samples : (participants, L, parameters) in the inference space."""
    rows = []
    for participant, x, block in zip(participants, observed, samples):
        density = flow_log_density(posterior_, x, block)
        best = highest_density_draw(density)
        for d, parameter in enumerate(parameters):
            value = float(parameter.from_inference(np.asarray(block[best, d])))
            rows.append([participant, parameter.key, number(value), str(best), number(float(density[best]))])
    return csv_text(list(POINT_COLUMNS), rows)
