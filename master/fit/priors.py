"""A fit's priors: each fitted parameter with its prior and its inference space, and the draws of the simulated
participants (training and held out) and their seeds.

The estimator works in an *inference space*: the logarithm of a log-uniform parameter, the parameter itself
otherwise, where every prior is a uniform or a (truncated) normal.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import numpy as np

PRIORS = ("uniform", "log-uniform", "normal")
CALIBRATION_DESIGNS = ("random", "latin-hypercube")  # how the held-out participants are drawn: draw_participants
MAX_SIMULATIONS = 100_000  # the most simulated participants a fit draws, fit.simulations and fit.calibration together


@dataclass(frozen=True)
class Parameter:
    """One fitted parameter: its configuration key and its prior."""

    key: str                    # its name: the configuration key, e.g. decoder.visual_variance, or PROTOCOL:KEY
    prior: str                  # one of PRIORS
    low: float = -math.inf      # bounds, in the parameter's own units
    high: float = math.inf
    mean: float = 0.0           # normal only
    sd: float = 1.0
    protocol: str = ""          # the one protocol it belongs to (a design value its study did not report); "": all

    @property
    def config_key(self) -> str:
        """The configuration key it sets: ``key`` without its protocol."""
        return self.key.removeprefix(f"{self.protocol}:") if self.protocol else self.key

    @property
    def log(self) -> bool:
        """Whether the inference space is the parameter's logarithm."""
        return self.prior == "log-uniform"

    def to_inference(self, values):
        """Values of the parameter in the inference space.

        Parameters
        ----------
        values : array_like
            Any shape, in the parameter's own units.

        Returns
        -------
        numpy.ndarray
            The same shape, float: their logarithm for a log-uniform prior, else the values.
        """
        return np.log(values) if self.log else np.asarray(values, dtype=float)

    def from_inference(self, values):
        """Values of the inference space in the parameter's own units, the inverse of :meth:`to_inference`.

        Parameters
        ----------
        values : array_like
            Any shape, in the inference space.

        Returns
        -------
        numpy.ndarray
            The same shape, float: their exponential for a log-uniform prior, else the values.
        """
        return np.exp(values) if self.log else np.asarray(values, dtype=float)

    def quantile(self, unit):
        """The prior's quantile function in the inference space: the values at which its distribution function
        is ``unit`` (in [0, 1])."""
        from scipy import stats

        low, high = self.to_inference(self.low), self.to_inference(self.high)
        if self.prior == "normal":
            return stats.truncnorm.ppf(unit, (low - self.mean) / self.sd, (high - self.mean) / self.sd,
                                       loc=self.mean, scale=self.sd)
        return low + np.asarray(unit, dtype=float) * (high - low)

    def describe(self) -> dict:
        """The parameter for run.json: its key and prior, a normal's mean and sd, and its finite bounds."""
        text = {"key": self.key, "prior": self.prior}
        if self.prior == "normal":
            text.update(mean=self.mean, sd=self.sd)
        for bound in ("low", "high"):
            if math.isfinite(getattr(self, bound)):
                text[bound] = getattr(self, bound)
        return text


def draw_prior(parameters: list[Parameter], count: int, seed: int) -> np.ndarray:
    """``count`` draws of the prior, (count, parameters), in the inference space; the same seed, the same draws."""
    from scipy import stats

    rng = np.random.default_rng([seed, 0])
    columns = []
    for parameter in parameters:
        low, high = parameter.to_inference(parameter.low), parameter.to_inference(parameter.high)
        if parameter.prior == "normal":
            a, b = (low - parameter.mean) / parameter.sd, (high - parameter.mean) / parameter.sd
            columns.append(stats.truncnorm.rvs(a, b, loc=parameter.mean, scale=parameter.sd, size=count,
                                               random_state=rng))
        else:
            columns.append(rng.uniform(low, high, size=count))
    return np.stack(columns, axis=1)


def draw_participants(parameters: list[Parameter], settings: dict) -> np.ndarray:
    """Every simulated participant's draw, (simulations + calibration, parameters), in the inference space: the
    training participants first, then the held-out ones.

    ``fit.calibration_design = "random"``: all rows one :func:`draw_prior`. ``"latin-hypercube"``: the same
    training rows, the held-out rows a Latin hypercube through each prior's quantile function (McKay, Beckman &
    Conover 1979, Technometrics 21:239; scipy's ``qmc.LatinHypercube``), so that each of the n equal-probability
    strata of every prior holds exactly one held-out truth. For a parameter the data barely inform, a
    posterior's rank is about the prior's distribution function at the truth, so with random truths the SBC
    tests and the coverage test the draws' own uniformity as much as the estimator; stratified truths remove that
    part. The iid rank tests are then conservative."""
    from scipy.stats import qmc

    training, held_out = settings["simulations"], settings["calibration"]
    drawn = draw_prior(parameters, training + held_out, settings["seed"])
    if settings["calibration_design"] == "latin-hypercube" and held_out:
        unit = qmc.LatinHypercube(d=len(parameters), rng=np.random.default_rng([settings["seed"], 2])).random(held_out)
        drawn[training:] = np.stack([p.quantile(unit[:, d]) for d, p in enumerate(parameters)], axis=1)
    return drawn


def simulation_seed(seed: int, number: int, stream: str = "train") -> int:
    """The master seed (experiment.seed) of simulated participant ``number``: its own tactile delays."""
    digest = hashlib.sha256(f"rhi fit/{seed}/{stream}/{number}".encode()).digest()
    return int.from_bytes(digest[:8], "little") >> 1
