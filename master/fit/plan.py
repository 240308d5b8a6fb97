"""FIT.toml read and checked: which parameters to fit and their priors, the simulations, the estimator
(:mod:`rhi.master.fit.estimator_settings`), the design every simulation runs.

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

The priors and the draws of the simulated participants are :mod:`rhi.master.fit.priors`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

from rhi.master import models
from rhi.master.cosim import ConfigError
from rhi.master.runtime.pool import workers_problem
from rhi.master import config as configuration
from rhi.master.config.sources import TASK_SOURCES, batchable_keys
from rhi.master.models.base import config_key
from rhi.master.config.sources import declared_range
from rhi.master.fit.columns import MEASURES, MODEL_MEASURES, is_measure, measures_of, probe_time
from rhi.master.fit.data import MAX_NOISE_SD, Data, check_against
from rhi.master.fit.estimator_settings import ESTIMATOR_DEFAULTS, MAX_ESTIMATOR, MAX_LEARNING_RATE, read_estimator
from rhi.master.fit.priors import (CALIBRATION_DESIGNS, MAX_SIMULATIONS, PRIORS, Parameter, draw_participants,
                                   draw_prior, simulation_seed)

# what other modules import from here, the priors and the estimator's limits defined in their own modules
__all__ = ["FitPlan", "read_plan", "with_design", "parameter_tables", "population_field", "parameter_key",
           "read_parameter", "FIT_KEYS", "WHOLE", "Parameter", "draw_prior", "draw_participants", "simulation_seed",
           "PRIORS", "CALIBRATION_DESIGNS", "MAX_SIMULATIONS", "ESTIMATOR_DEFAULTS", "MAX_ESTIMATOR",
           "MAX_LEARNING_RATE", "MAX_NOISE_SD"]

FIT_KEYS = ("model", "quick", "simulations", "calibration", "calibration_design", "seed", "trials_per_cell",
            "participants_per_batch", "workers", "measures", "posterior_samples", "calibration_samples",
            "predictive_draws", "predictive_participants", "noise", "participant_noise", "estimator", "parameters")
WHOLE = {"simulations": 1000, "calibration": 100, "seed": 0, "trials_per_cell": 1, "participants_per_batch": 10,
         "posterior_samples": 1000, "calibration_samples": 99, "predictive_draws": 10, "predictive_participants": 8}


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
    participant_noise : dict of str to float
        Measure -> sd of each participant's own measurement error (``fit.participant_noise``), added to every
        simulated participant's value before a group's statistics, in the measure's unit; empty: none.
    estimator : dict
        ``fit.estimator``'s settings, the defaults filled in.
    designs : list of dict
        A fit of several protocols (the data's ``protocol`` column): per protocol, in the data's order, the dotted
        keys its configuration sets over ``base`` (its design, its file's tables); empty for one design.
    protocols : list of str
        The protocols of ``designs``, as the data's column names them.
    """

    parameters: list[Parameter]
    base: dict                           # the configuration every simulation starts from (design included)
    settings: dict                       # [fit]'s whole numbers, model, quick, workers
    measures: list[str]                  # the summary statistics' measures, per design cell
    noise: dict[str, float]              # measure -> sd of the observation noise added to a simulated cell mean
    estimator: dict = field(default_factory=dict)
    designs: list[dict] = field(default_factory=list)  # per protocol: the keys its configuration sets over base
    participant_noise: dict[str, float] = field(default_factory=dict)  # measure -> sd of a participant's own error
    protocols: list[str] = field(default_factory=list)  # the protocol of each of designs

    def configs(self) -> list[dict]:
        """The configuration each protocol's simulated participants run (one design: ``base``)."""
        return [configuration.merge(self.base, configuration.nest(keys)) for keys in self.designs] or [self.base]


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


def read_parameters(tables: dict, base: dict, protocols: dict[str, dict]) -> list[Parameter]:
    """``fit.parameters``' priors (:func:`read_parameter`). A key written ``PROTOCOL:KEY`` (PROTOCOL as the data's
    protocol column names it; ``protocols`` maps each to its configuration) belongs to that protocol alone: a design
    value its study did not report (a stroke rate), fitted as a nuisance parameter, read against that protocol's
    configuration and set in its simulations only."""
    fitted = []
    for written, spec in parameter_tables(tables):
        protocol, colon, key = written.rpartition(":")
        if not colon:
            fitted.append(read_parameter(written, spec, base))
            continue
        if protocol not in protocols:
            raise ConfigError(f"fit.parameters.{written}: {protocol!r} is not a protocol of the data file (its "
                              f"protocols: {', '.join(protocols) or 'none: it has no protocol column'})")
        fitted.append(replace(read_parameter(key, spec, protocols[protocol], written), key=written, protocol=protocol))
    return fitted


def read_parameter(written: str, spec, config: dict, written_as: str | None = None) -> Parameter:
    """The :class:`Parameter` that ``fit.parameters.WRITTEN = spec`` describes, checked: a key a fit can vary, the
    prior's keys and finite numbers, and finite bounds that are valid values of the key; ConfigError otherwise.
    ``written_as``: how the fit file writes it, where other than ``written`` (a protocol's parameter)."""
    where = f"fit.parameters.{written_as or written}"
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
    configuration.validate(base)  # a value the design replaces (experiment.trials) is refused all the same
    # several protocols: each its own design over the fit file's configuration
    protocols = {part.protocol: with_protocol(base, part, whole["trials_per_cell"]) for part in data.parts}
    designs = [protocol_keys(base, config) for config in protocols.values()]
    if not data.parts:
        base = with_design(base, data, whole["trials_per_cell"])
    parameters = settings.get("parameters")
    if not isinstance(parameters, dict) or not parameters:
        raise ConfigError("fit.parameters: name at least one parameter to fit, each a table with its prior")
    fitted = read_parameters(parameters, base, protocols)
    if len({p.key for p in fitted}) != len(fitted):
        raise ConfigError("fit.parameters names one parameter twice")
    for part, keys in zip(data.parts, designs):
        for p in fitted:
            if p.protocol in ("", part.protocol) and (p.config_key in keys or
                                                     any(key.startswith(f"{p.config_key}.") for key in keys)):
                raise ConfigError(f"protocol {part.protocol}: sets {p.config_key}, a fitted parameter; a protocol "
                                  "gives the study's design, the fit its parameters")
    measures = settings.get("measures", data.measures)
    if not isinstance(measures, list) or not measures or any(m not in data.measures for m in measures):
        raise ConfigError(f"fit.measures = {measures!r} must list measures of the data file ({', '.join(data.measures)})")
    measures = [m for m in data.measures if m in measures]  # the statistics' order (measure_order)
    recorded = models.of(base).measures
    for measure in dict.fromkeys(base for m in measures for base in measures_of(m)):
        if measure in MODEL_MEASURES and measure not in recorded:
            raise ConfigError(f"{Path(data.path).name}: column {measure}: model {model!r} does not record it (its own "
                              f"measures: {', '.join(recorded) or 'none'}); fit it with a model that does")
    noise = read_noise(settings, "noise", data, measures)
    own = read_noise(settings, "participant_noise", data, measures)
    chosen = read_estimator(settings.get("estimator", {}), len(fitted), len(data.cells) * len(measures))
    return FitPlan(fitted, base, {**whole, "model": model, "quick": quick, "workers": workers,
                                     "calibration_design": design}, measures,
                   {m: float(noise.get(m, 0.0)) for m in measures}, chosen, designs,
                   {m: float(sd) for m, sd in own.items() if sd > 0}, list(protocols))


def read_noise(settings: dict, name: str, data: Data, measures: list[str]) -> dict:
    """``fit.noise`` (an sd added to each simulated cell mean) or ``fit.participant_noise`` (an sd added to each
    simulated participant's value, a group's measurement error: only a measure, not its spread) checked: measure ->
    a finite sd >= 0 in the measure's unit; ConfigError otherwise."""
    noise = settings.get(name, {})
    if not isinstance(noise, dict):
        raise ConfigError(f"fit.{name} must be a table: measure = sd of the observation noise")
    for key, value in noise.items():
        if not is_measure(key) or (name == "participant_noise" and key not in measures):
            known = [m for m in measures if is_measure(m)] if name == "participant_noise" else [
                *MEASURES, *(m for m in data.measures if probe_time(m) is not None)]
            raise configuration.unknown_key(f"fit.{name}.{key}", known, "fit")
        if name == "noise" and key in data.noise:
            raise ConfigError(f"fit.noise.{key}: the data's column {key}_sem gives each cell's noise sd; give one of them")
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not (math.isfinite(value) and value >= 0):
            raise ConfigError(f"fit.{name}.{key} = {value!r} must be a number >= 0")
        if value > MAX_NOISE_SD:
            raise ConfigError(f"fit.{name}.{key} = {value!r} is over the limit of {MAX_NOISE_SD:g} (in the measure's "
                              "unit: 10 m of drift, 1 kN of force, far beyond any drift the arm's reach or force its "
                              "servos allow; a larger sd buries every simulation in noise)")
    return noise


PROTOCOL_REFUSED = ("fit", "population", "sweep")  # a protocol file gives a study's design, not a fit's or a sweep's


def with_protocol(base: dict, part: Data, trials: int) -> dict:
    """``base`` running the part's design under its protocol file (its tables over the fit file's; its
    ``experiment.trials``, when it sets it, the group's n in place of ``trials``); ConfigError naming the file."""
    path = part.protocol_path()
    tables = configuration.read_toml(path)
    for table in PROTOCOL_REFUSED:
        if table in tables:
            raise ConfigError(f"protocol {part.protocol}: a protocol file gives a study's design; its [{table}] "
                              "belongs in the fit file")
    try:
        config = configuration.merge(base, tables)
        return with_design(config, part, tables.get("experiment", {}).get("trials", trials))
    except ConfigError as error:
        raise ConfigError(f"protocol {part.protocol}: {error}") from None


def protocol_keys(base: dict, config: dict) -> dict:
    """The dotted keys whose values ``config`` sets other than ``base``: a protocol's part of a sweep point."""
    from rhi.master.sweeps.plan import flatten

    before = {table: flatten(values) for table, values in base.items() if isinstance(values, dict)}
    return {f"{table}.{key}": value for table, values in config.items() if isinstance(values, dict)
            for key, value in flatten(values).items() if before.get(table, {}).get(key, ...) != value}


def with_design(config: dict, data: Data, trials: int) -> dict:
    """``config`` running exactly the data's design: its conditions and stimulations (a contrast's two), one trial
    length."""
    config = configuration.merge(config, {
        "conditions": dict(data.conditions),
        "stimulations": {name: {"delay_min": delay, "delay_max": delay} for name, delay in data.stimulations.items()}})
    check_against(data, config)
    config["experiment"]["conditions"] = sorted({c for c, _ in data.cells})
    config["experiment"]["stimulations"] = sorted({s for _, named in data.cells
                                                   for s in data.contrasts.get(named, (named,))})
    config["experiment"]["trials"] = trials
    if data.probe_times():  # the drift read when the data read it (checked against the trial's length below)
        config["experiment"]["probe_times"] = sorted({*config["experiment"]["probe_times"], *data.probe_times()})
    if data.time_s is not None:
        steps = round(data.time_s / config["experiment"]["step_size"])
        if steps < 1 or abs(steps * config["experiment"]["step_size"] - data.time_s) > 1e-9 * max(1.0, data.time_s):
            raise ConfigError(f"{data.path}: time_s = {data.time_s:g} s is not a whole number of steps of "
                              f"{config['experiment']['step_size']:g} s")
        config["experiment"]["steps"] = steps
    configuration.validate(config)
    return config


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
