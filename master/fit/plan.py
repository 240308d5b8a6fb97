"""FIT.toml: which parameters to fit, their priors, the simulations and the estimator; the prior sampled.

A fit file is an ordinary configuration file (any tables of ``master/config/defaults.toml``, fixed for every
simulation) plus a ``[fit]`` table (docs/fit.md)::

    [fit]
    simulations = 1000                 # prior draws to train on (simulated participants)
    calibration = 100                  # held-out draws for the calibration (SBC, coverage, recovery)
    seed = 0
    [fit.parameters."decoder.visual_variance"]
    prior = "log-uniform"              # uniform, log-uniform or normal (mean, sd; low, high bound it)
    low = 5.0
    high = 80.0

The estimator works in an *inference space*: the logarithm of a log-uniform parameter, the parameter
itself otherwise, where every prior is a uniform or a (truncated) normal.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field

import numpy as np

from rhi.master import models
from rhi.master.cosim import ConfigError
from rhi.master.runtime.pool import workers_problem
from rhi.master import config as configuration
from rhi.master.config.sources import TASK_SOURCES, batchable_keys
from rhi.master.models.base import config_key
from rhi.master.config.sources import declared_range
from rhi.master.fit.data import MAX_NOISE_SD, MEASURES, SPREADS, Data, check_against

PRIORS = ("uniform", "log-uniform", "normal")
FIT_KEYS = ("model", "quick", "simulations", "calibration", "calibration_design", "seed", "trials_per_cell",
            "participants_per_batch", "workers", "measures", "posterior_samples", "calibration_samples",
            "predictive_draws", "predictive_participants", "noise", "estimator", "parameters")
# the flow's size, batch and learning rate are sbi's own defaults (posterior_nn, NPE.train)
ESTIMATOR_DEFAULTS = {"density": "maf", "hidden_features": 50, "transforms": 5, "batch_size": 200,
                      "max_epochs": 500, "learning_rate": 5e-4, "threads": 2, "ensemble": 1, "space": "unconstrained",
                      "statistics": "normal-scores"}
CHOICES = {"density": ("maf", "nsf", "mdn"), "space": ("bounded", "unconstrained"),
           "statistics": ("z-score", "normal-scores")}
WHOLE = {"simulations": 1000, "calibration": 100, "seed": 0, "trials_per_cell": 1, "participants_per_batch": 10,
         "posterior_samples": 1000, "calibration_samples": 99, "predictive_draws": 10, "predictive_participants": 8}
MAX_SIMULATIONS = 100_000
# The largest value of each whole-number estimator key (docs/safety.md): a flow twenty times sbi's width (50) and
# about thirteen times its depth (5) is far beyond what MAX_SIMULATIONS participants can train; an ensemble of 32;
# a batch of every simulation; 100 000 epochs (early stopping ends sbi's training long before); torch's threads
# bounded as train.threads is. A learning rate above 1 moves each weight by more than its initial scale per step.
MAX_ESTIMATOR = {"hidden_features": 1024, "transforms": 64, "batch_size": MAX_SIMULATIONS, "max_epochs": 100_000,
                 "threads": configuration.MAX_THREADS, "ensemble": 32}
MAX_LEARNING_RATE = 1.0
# Weights per transform of sbi's flows, at most this many times hidden x (hidden + parameters + statistics + 1)
# (measured on maf, nsf and mdn, 1 to 16 parameters and 1 to 24 statistics: at most 6.1); bytes per weight in
# training: the weight, its gradient and Adam's two moments, float32; bytes of activations kept for the backward
# pass per batch row, transform and hidden unit (measured in one training step: maf 43, nsf 87, mdn 31).
FLOW_WEIGHTS_FACTOR = 8
BYTES_PER_TRAINED_WEIGHT = 16
ACTIVATION_BYTES = 128
CALIBRATION_DESIGNS = ("random", "latin-hypercube")  # how the held-out participants are drawn: draw_participants


@dataclass(frozen=True)
class Parameter:
    """One fitted parameter: its configuration key and its prior."""

    key: str                    # the configuration key, e.g. decoder.visual_variance
    prior: str                  # one of PRIORS
    low: float = -math.inf      # bounds, in the parameter's own units
    high: float = math.inf
    mean: float = 0.0           # normal only
    sd: float = 1.0

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


@dataclass(frozen=True)
class FitPlan:
    """A checked fit file: the parameters to fit, the configuration every simulation starts from, the settings.

    Attributes
    ----------
    parameters : list of Parameter
        The fitted parameters and their priors.
    base : dict
        The configuration every simulation starts from, the data's design included.
    settings : dict
        ``[fit]``'s whole numbers, and its model, quick, workers and calibration design.
    measures : list of str
        The summary statistics' measures per design cell (drift_cm, force_n), in that order.
    noise : dict of str to float
        Measure -> sd of the observation noise added to a simulated cell mean, in the measure's unit.
    estimator : dict
        ``fit.estimator``'s settings, the defaults filled in.
    """

    parameters: list[Parameter]
    base: dict                           # the configuration every simulation starts from (design included)
    settings: dict                       # [fit]'s whole numbers, model, quick, workers
    measures: list[str]                  # the summary statistics' measures, per design cell
    noise: dict[str, float]              # measure -> sd of the observation noise added to a simulated cell mean
    estimator: dict = field(default_factory=dict)


def population_field(written: str, config: dict) -> str | None:
    """``population.KEY.FIELD`` (a field of an entry of the configuration's ``[population]``: its median, its
    spread or a bound) as written, a fit of a population's median or spread; None for any other name; ConfigError
    for a population name that names no such field."""
    if not written.startswith("population."):
        return None
    key, _, field_name = written.removeprefix("population.").rpartition(".")
    entry = config.get("population", {}).get(key)
    if entry is None:
        raise ConfigError(f"fit.parameters.{written}: the fit file's [population] has no entry {key!r} "
                          f"({', '.join(config.get('population', {})) or 'none'})")
    from rhi.master.config.population import fields

    if field_name not in fields(entry["distribution"]):
        raise ConfigError(f"fit.parameters.{written}: a {entry['distribution']} entry has no field {field_name!r} "
                          f"to fit (its fields: {', '.join(fields(entry['distribution'])) or 'none'})")
    return written


def parameter_key(written: str, config: dict) -> str:
    """The configuration key a fit file names, as a key (``brain.sync_sd``), a component parameter
    (``brain.timing_noise_sd`` -> ``causal.timing_noise_sd``) or a population's field
    (``population.brain.gamma0.logit_sd``, :func:`population_field`); ConfigError unless a fit can vary it."""
    if population_field(written, config):
        return written
    key = written
    sources = {**TASK_SOURCES, **models.of(config).parameter_sources}
    if written in sources and config_key(sources[written]):
        key = config_key(sources[written])
    allowed = sorted(batchable_keys(config))
    if key not in allowed:
        table, _, name = key.partition(".")
        if table in config and isinstance(config[table], dict) and name in config[table]:
            raise ConfigError(f"fit.parameters.{written}: not a parameter a fit can vary (a float that sets a "
                              f"component parameter per trial: {', '.join(allowed)})")
        raise configuration.unknown_key(f"fit.parameters.{written}", [k.partition(".")[2] for k in allowed
                                                                        if k.startswith(table + ".")] or allowed)
    return key


def read_parameter(written: str, spec, config: dict) -> Parameter:
    """The :class:`Parameter` that ``fit.parameters.WRITTEN = spec`` describes, checked: a key a fit can vary, the
    prior's keys and finite numbers, and finite bounds that are valid values of the key; ConfigError otherwise."""
    where = f"fit.parameters.{written}"
    if not isinstance(spec, dict):
        raise ConfigError(f"{where} must be a table with a prior (uniform, log-uniform or normal)")
    key = parameter_key(written, config)
    allowed = {"uniform": {"prior", "low", "high"}, "log-uniform": {"prior", "low", "high"},
               "normal": {"prior", "mean", "sd", "low", "high"}}
    prior = spec.get("prior")
    if prior not in PRIORS:
        raise ConfigError(f"{where}.prior = {prior!r} is not one of {', '.join(PRIORS)}")
    for name, value in spec.items():
        if name not in allowed[prior]:
            raise configuration.unknown_key(f"{where}.{name}", sorted(allowed[prior]), "fit")
        if name != "prior" and (not isinstance(value, (int, float)) or isinstance(value, bool)
                                or not math.isfinite(value)):
            raise ConfigError(f"{where}.{name} = {value!r} must be a finite number")
    needed = {"low", "high"} if prior != "normal" else {"mean", "sd"}
    missing = sorted(needed - set(spec))
    if missing:
        raise ConfigError(f"{where}: a {prior} prior needs {' and '.join(missing)}")
    parameter = Parameter(key, prior, float(spec.get("low", -math.inf)), float(spec.get("high", math.inf)),
                          float(spec.get("mean", 0.0)), float(spec.get("sd", 1.0)))
    if not parameter.low < parameter.high:
        raise ConfigError(f"{where}: low must be below high, got {parameter.low} and {parameter.high}")
    if prior == "log-uniform" and parameter.low <= 0:
        raise ConfigError(f"{where}: a log-uniform prior needs low > 0, got {parameter.low}")
    if prior == "normal" and parameter.sd <= 0:
        raise ConfigError(f"{where}.sd must be positive, got {parameter.sd}")
    declared = declared_range(config, key)  # the prior's support within the range the component declares
    if declared is not None:
        path, lowest, highest, unit = declared
        if (lowest is not None and parameter.low < lowest) or (highest is not None and parameter.high > highest):
            side = "low" if lowest is not None and parameter.low < lowest else "high"
            raise ConfigError(f"{where}: the {prior} prior's support [{parameter.low:g}, {parameter.high:g}] leaves "
                              f"{path}'s range [{'-inf' if lowest is None else f'{lowest:g}'}, "
                              f"{'inf' if highest is None else f'{highest:g}'}] {unit}: give {side} within that range "
                              f"(a prior draws values the simulator refuses, and a posterior follows it there)")
    for bound in (parameter.low, parameter.high):  # the prior's support must be a valid configuration
        if math.isfinite(bound):
            try:
                configuration.validate(configuration.merge(config, configuration.nest({key: bound})))
            except ConfigError as error:
                raise ConfigError(f"{where}: the bound {bound:g} is not a valid value ({error})") from None
    return parameter


def read_plan(path: str, data: Data, model: str | None = None) -> FitPlan:
    """Read and check FIT.toml against the data's design; the base configuration of every simulation."""
    fixed = configuration.read_toml(path)
    settings = fixed.pop("fit", None)
    if not isinstance(settings, dict):
        raise ConfigError(f"fit file {path} has no [fit] table (it says which parameters to fit)")
    for key in settings:
        if key not in FIT_KEYS:
            raise configuration.unknown_key(f"fit.{key}", FIT_KEYS, "fit")
    model = model or settings.get("model", "paper")
    models.checked(model, "fit.model")
    quick = settings.get("quick", False)
    if not isinstance(quick, bool):
        raise ConfigError(f"fit.quick must be true or false, got {quick!r}")
    whole = {}
    for key, default in WHOLE.items():
        value = settings.get(key, default)
        lowest = 0 if key in ("seed", "calibration", "predictive_draws", "predictive_participants") else 1
        if not isinstance(value, int) or isinstance(value, bool) or value < lowest:
            raise ConfigError(f"fit.{key} must be a whole number of at least {lowest}, got {value!r}")
        if key in ("simulations", "calibration") and value > MAX_SIMULATIONS:
            raise ConfigError(f"fit.{key} = {value} is over the limit of {MAX_SIMULATIONS} (the most simulated "
                              "participants a fit runs, fit.simulations and fit.calibration together)")
        if value > MAX_SIMULATIONS * 10:
            raise ConfigError(f"fit.{key} = {value} is over the limit of {MAX_SIMULATIONS * 10} (ten times the most "
                              "simulated participants a fit runs)")
        whole[key] = value
    if whole["simulations"] + whole["calibration"] > MAX_SIMULATIONS:
        raise ConfigError(f"fit.simulations + fit.calibration is over the limit of {MAX_SIMULATIONS}")
    if whole["simulations"] < 10:
        raise ConfigError(f"fit.simulations must be at least 10 to train an estimator, got {whole['simulations']}")
    design = settings.get("calibration_design", CALIBRATION_DESIGNS[0])
    if design not in CALIBRATION_DESIGNS:
        raise ConfigError(f"fit.calibration_design = {design!r} is not one of {', '.join(CALIBRATION_DESIGNS)}")
    workers = settings.get("workers")
    if workers is not None and workers_problem("fit.workers", workers):
        raise ConfigError(workers_problem("fit.workers", workers))
    base = configuration.merge(configuration.load(quick=quick, model_name=model), fixed)
    if "decoders" not in fixed.get("experiment", {}):
        base["experiment"]["decoders"] = ["conv"]
    if len(base["experiment"]["decoders"]) != 1:
        raise ConfigError("experiment.decoders: a fit simulates one decoder; name one")
    base = with_design(base, data, whole["trials_per_cell"])
    parameters = settings.get("parameters")
    if not isinstance(parameters, dict) or not parameters:
        raise ConfigError("fit.parameters: name at least one parameter to fit, each a table with its prior")
    fitted = [read_parameter(written, spec, base) for written, spec in parameter_tables(parameters)]
    if len({p.key for p in fitted}) != len(fitted):
        raise ConfigError("fit.parameters names one parameter twice")
    measures = settings.get("measures", data.measures)
    if not isinstance(measures, list) or not measures or any(m not in data.measures for m in measures):
        raise ConfigError(f"fit.measures = {measures!r} must list measures of the data file ({', '.join(data.measures)})")
    measures = [m for m in (*MEASURES, *SPREADS) if m in measures]
    noise = settings.get("noise", {})
    if not isinstance(noise, dict):
        raise ConfigError("fit.noise must be a table: measure = sd of the observation noise")
    for key, value in noise.items():
        if key not in MEASURES:
            raise configuration.unknown_key(f"fit.noise.{key}", MEASURES, "fit")
        if key in data.noise:
            raise ConfigError(f"fit.noise.{key}: the data's column {key}_sem gives each cell's noise sd; give one of them")
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not (math.isfinite(value) and value >= 0):
            raise ConfigError(f"fit.noise.{key} = {value!r} must be a number >= 0")
        if value > MAX_NOISE_SD:
            raise ConfigError(f"fit.noise.{key} = {value!r} is over the limit of {MAX_NOISE_SD:g} (in the measure's "
                              "unit: 10 m of drift, 1 kN of force, far beyond any drift the arm's reach or force its "
                              "servos allow; a larger sd buries every simulation in noise)")
    estimator = settings.get("estimator", {})
    if not isinstance(estimator, dict):
        raise ConfigError("fit.estimator must be a table")
    for key, value in estimator.items():
        if key not in ESTIMATOR_DEFAULTS:
            raise configuration.unknown_key(f"fit.estimator.{key}", ESTIMATOR_DEFAULTS, "fit")
        check_estimator_key(key, value)
    chosen = {**ESTIMATOR_DEFAULTS, **estimator}
    check_estimator_memory(chosen, len(fitted), len(data.cells) * len(measures))
    return FitPlan(fitted, base, {**whole, "model": model, "quick": quick, "workers": workers,
                                     "calibration_design": design}, measures,
                   {m: float(noise.get(m, 0.0)) for m in measures}, chosen)


def check_estimator_key(key: str, value) -> None:
    """One ``fit.estimator`` key: one of its choices, or a number of its type within (0, its maximum]."""
    default = ESTIMATOR_DEFAULTS[key]
    if isinstance(default, str):
        if value not in CHOICES[key]:
            raise ConfigError(f"fit.estimator.{key} = {str(value)[:60]!r} is not one of {', '.join(CHOICES[key])}")
        return
    if (not isinstance(value, (int, float)) or isinstance(value, bool) or not value > 0 or not math.isfinite(value)
            or (isinstance(default, int) and not isinstance(value, int))):
        raise ConfigError(f"fit.estimator.{key} = {value!r} must be a positive "
                          f"{'whole number' if isinstance(default, int) else 'finite number'}")
    top = MAX_ESTIMATOR.get(key, MAX_LEARNING_RATE)
    if value > top:
        raise ConfigError(f"fit.estimator.{key} = {value!r} is over the limit of {top:g} ({ESTIMATOR_LIMITS_WHY[key]})")


ESTIMATOR_LIMITS_WHY = {
    "hidden_features": "about twenty times sbi's 50: wider than the most simulations a fit runs can train",
    "transforms": "about thirteen times sbi's 5: deeper than the most simulations a fit runs can train",
    "batch_size": f"fit.simulations is at most {MAX_SIMULATIONS}: one batch of them all",
    "max_epochs": "sbi's early stopping ends a training long before",
    "threads": "twice the hardware threads of the largest common server, as train.threads",
    "ensemble": "each member is one more training of the whole estimator",
    "learning_rate": "a step that moves each weight by more than its initial scale: the loss diverges"}


def estimator_memory(settings: dict, parameters: int, statistics: int) -> int:
    """About how many bytes training the estimators of ``settings`` needs at its peak: every ensemble member's
    weights (with their gradients and Adam's moments) and one batch's activations (FLOW_WEIGHTS_FACTOR and the
    bytes above: upper bounds, to refuse what cannot fit, not to plan)."""
    hidden, transforms = settings["hidden_features"], settings["transforms"]
    weights = FLOW_WEIGHTS_FACTOR * transforms * hidden * (hidden + parameters + statistics + 1)
    activations = settings["batch_size"] * transforms * hidden * ACTIVATION_BYTES
    return settings["ensemble"] * weights * BYTES_PER_TRAINED_WEIGHT + activations


def check_estimator_memory(settings: dict, parameters: int, statistics: int) -> None:
    """A ConfigError, before any simulation, for an estimator whose training needs more memory than this machine
    has, saying how much."""
    needed, available = estimator_memory(settings, parameters, statistics), configuration.physical_memory()
    if available and needed > available:
        raise ConfigError(f"training the estimator would need about {configuration.size(needed)} of memory "
                          f"({settings['ensemble']} x a {settings['density']} of {settings['transforms']} transforms "
                          f"of {settings['hidden_features']} hidden features, batches of {settings['batch_size']}), "
                          f"more than this machine's {configuration.size(available)}; lower fit.estimator."
                          "hidden_features, transforms, ensemble or batch_size")


def with_design(config: dict, data: Data, trials: int) -> dict:
    """``config`` running exactly the data's design: its conditions and stimulations, one trial length."""
    config = configuration.merge(config, {
        "conditions": dict(data.conditions),
        "stimulations": {name: {"delay_min": delay, "delay_max": delay} for name, delay in data.stimulations.items()}})
    check_against(data, config)
    config["experiment"]["conditions"] = sorted({c for c, _ in data.cells})
    config["experiment"]["stimulations"] = sorted({s for _, s in data.cells})
    config["experiment"]["trials"] = trials
    if data.time_s is not None:
        steps = round(data.time_s / config["experiment"]["step_size"])
        if steps < 1 or abs(steps * config["experiment"]["step_size"] - data.time_s) > 1e-9 * max(1.0, data.time_s):
            raise ConfigError(f"{data.path}: time_s = {data.time_s:g} s is not a whole number of steps of "
                              f"{config['experiment']['step_size']:g} s")
        config["experiment"]["steps"] = steps
    configuration.validate(config)
    return config


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


def parameter_tables(table: dict, prefix: str = "") -> list[tuple[str, object]]:
    """``fit.parameters`` as (dotted key, prior table) pairs, quoted (``"brain.sync_sd"``) or nested keys alike:
    a table with a ``prior`` is a prior."""
    found = []
    for key, value in table.items():
        if isinstance(value, dict) and "prior" not in value:
            found += parameter_tables(value, f"{prefix}{key}.")
        else:
            found.append((f"{prefix}{key}", value))
    return found
