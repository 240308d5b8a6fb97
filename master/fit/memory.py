"""`rhi fit` in memory, over arrays: simulate participants, train the estimator, sample a posterior.

The three calls sbi's users know (simulate / train / sample), each on numpy arrays. ``rhi fit`` composes the same
pieces with a resumable folder around them (:mod:`rhi.master.fit.run`: its simulations are a sweep folder, its
estimator a file); these run everything here, write nothing, and give the same numbers.

Example::

    from rhi.master.fit import memory
    data = read_data("data.csv"); plan = read_plan("fit.toml", data)
    theta = memory.draw(plan, 200)                      # (200, P), the inference space
    x = memory.simulate(plan, data, theta)              # (200, cells x measures)
    posterior = memory.train(plan, theta, x)
    samples = memory.sample(plan, posterior, x[0], 100, seed=1)   # (100, P), the parameters' own units
"""
from __future__ import annotations

import numpy as np

from rhi.master.fit.data import Data
from rhi.master.fit.plan import FitPlan, draw_prior, simulation_seed
from rhi.master.fit.simulate import participants_sweep, simulated_statistics


def draw(plan: FitPlan, count: int) -> np.ndarray:
    """``count`` draws of the priors, (count, parameters), in the inference space (from the fit's seed)."""
    return draw_prior(plan.parameters, count, plan.settings["seed"])


def simulate(plan: FitPlan, data: Data, theta: np.ndarray, stream: str = "prior") -> np.ndarray:
    """Simulated participants' summary statistics, with the fit's observation noise.

    Parameters
    ----------
    plan : FitPlan
        The fit (:func:`rhi.master.fit.plan.read_plan`).
    data : Data
        The data file whose design cells the participants are run over.
    theta : numpy.ndarray
        (n, parameters): each participant's draw, in the inference space (:func:`draw`).
    stream : str
        Names the participants' seeds and noise (``rhi fit``'s training set is ``"prior"``).

    Returns
    -------
    numpy.ndarray
        (n, cells x measures): each participant's cell means, cell-major; NaN where a trial failed. Row k equals
        ``rhi fit``'s row k of the same stream (the same lockstep batches, the same seeds).
    """
    from rhi.master.sweeps.runner import run_in_memory

    sweep = participants_sweep(plan, np.asarray(theta, dtype=float), stream)
    records = run_in_memory(sweep)
    return simulated_statistics(plan, sweep, records, data, stream)


def train(plan: FitPlan, theta: np.ndarray, x: np.ndarray):
    """The posterior estimator trained on (theta, x): ``fit.estimator.ensemble`` members, each from its own seed
    (as ``rhi fit`` trains them), as one posterior.

    Parameters
    ----------
    theta : numpy.ndarray
        (n, parameters) in the inference space.
    x : numpy.ndarray
        (n, statistics), finite rows only.
    """
    from rhi.master.fit import inference

    seeds = [simulation_seed(plan.settings["seed"], k, "estimator") % 2**62 for k in range(plan.estimator["ensemble"])]
    estimators = [inference.train(plan.parameters, theta, x, plan.estimator, seed)[0].eval() for seed in seeds]
    return inference.posterior(plan.parameters, estimators, plan.estimator, x)


def sample(plan: FitPlan, posterior, observed: np.ndarray, count: int, seed: int) -> np.ndarray:
    """(count, parameters) draws of the posterior given one participant's statistics ``observed`` (statistics,),
    in the parameters' own units."""
    from rhi.master.fit import inference
    from rhi.master.fit.report import natural

    return natural(plan.parameters, inference.sample(posterior, np.asarray(observed, dtype=float), count, seed))


def at_point(plan: FitPlan, data: Data, point: dict[str, float], count: int = 20, stream: str = "point") -> np.ndarray:
    """``count`` simulated participants (or studies) at one point of the parameters, as :func:`simulate` makes them:
    the model at a fit's adopted point (point.csv's values) against the data it was fitted on.

    Parameters
    ----------
    point : dict of str to float
        Each fitted parameter's value in its own unit (the keys of ``plan.parameters``).
    count : int
        How many, each with its own seed of ``stream``.

    Returns
    -------
    numpy.ndarray
        (count, cells x measures), as :func:`simulate`'s.
    """
    missing = [p.key for p in plan.parameters if p.key not in point]
    if missing:
        raise KeyError(f"the point has no value of {', '.join(missing)}")
    row = [float(p.to_inference(point[p.key])) for p in plan.parameters]
    return simulate(plan, data, np.array([row] * count, dtype=float), stream)
