"""A population of participants: each named parameter drawn per simulated participant from a distribution.

A ``[population]`` table gives configuration keys (``brain.gamma0``, a model's own ``ownership.timing_jnd``)
a distribution over participants::

    [population]
    "ownership.timing_jnd" = {distribution = "log-normal", log_sd = 0.3}      # median: the key's own value
    "brain.gamma0" = {distribution = "logit-normal", logit_sd = 1.0, high = 0.5}
    "ownership.realignment_weight" = {distribution = "normal", sd = 0.1, low = 0.0, high = 1.0}
    "stimulus.period" = {distribution = "uniform", low = 1.5, high = 2.5}

Every distribution but ``uniform`` is centred on its ``median`` (default: the key's configured value);
``low`` and ``high`` truncate it (the draw comes from the distribution conditioned on the bounds). A
participant is one index of the protocol's trials (``experiment.trials``) under one master seed: the same
person runs every cell (decoder, condition, stimulation), as in a within-participant design. Each key of each
participant has its own stream, numpy's ``default_rng([participant_seed, POPULATION_STREAM, key_code])``, so
the same seed gives the same cohort, adding a key changes no other key's draws, and no existing stream (the
stimulus' ``default_rng(trial_seed)``, the brains' ``[trial_seed, 1]`` and ``[trial_seed, 2]``) is touched.

A draw is one uniform variate u pushed through the distribution's quantile function (inverse transform
sampling; truncation maps u onto [F(low), F(high)] first). Every distribution is a monotone map of a
standard normal z: :data:`DISTRIBUTIONS` holds, per name, the function giving that map and its inverse.
"""
from __future__ import annotations

import functools
import hashlib
import math
import re
from dataclasses import dataclass
from typing import Callable

import numpy as np

from rhi.master.cosim import ConfigError

POPULATION_STREAM = 3  # the stimulus uses the trial seed itself, the causal and ownership brains streams 1 and 2
_KEY = re.compile(r"[a-z_][a-z_0-9]*\.[a-z_][a-z_0-9]*")
BOUNDS = ("low", "high")


def normal(median: float, sd: float):
    """Normal with mean = median and sd ``sd``: x = median + sd z (e.g. Johnson, Kotz & Balakrishnan 1994,
    *Continuous Univariate Distributions* vol. 1, ch. 13). Returns (z -> x, x -> z)."""
    return (lambda z: median + sd * z), (lambda x: (x - median) / sd)


def log_normal(median: float, log_sd: float):
    """Log-normal: ln x normal with mean ln(median) and sd ``log_sd`` (Johnson, Kotz & Balakrishnan 1994, ch. 14):
    x = median exp(log_sd z). Returns (z -> x, x -> z)."""
    return (lambda z: median * np.exp(log_sd * z)), (lambda x: np.log(np.asarray(x, dtype=float) / median) / log_sd)


def logit_normal(median: float, logit_sd: float):
    """Logit-normal on (0, 1): logit x normal with mean logit(median) and sd ``logit_sd`` (Aitchison & Shen 1980,
    Biometrika 67:261, the logistic-normal): x = expit(logit(median) + logit_sd z). Returns (z -> x, x -> z)."""
    from scipy import special  # here, not at the top: a command refused while its configuration loads never pays for it

    centre = special.logit(median)
    return (lambda z: special.expit(centre + logit_sd * z)), (lambda x: (special.logit(x) - centre) / logit_sd)


def uniform(low: float, high: float):
    """Uniform on [low, high]: x = low + (high - low) Phi(z), Phi the standard normal CDF (so u = Phi(z) is the
    uniform variate itself). Returns (z -> x, x -> z)."""
    from scipy import special

    return (lambda z: low + (high - low) * special.ndtr(z)), (lambda x: special.ndtri((x - low) / (high - low)))


@dataclass(frozen=True)
class Distribution:
    """One distribution over participants: its map of a standard normal, the field holding its spread ("" for
    none), and the values it can take (its support)."""

    transform: Callable | None
    spread: str
    support: tuple[float, float]


DISTRIBUTIONS = {
    "fixed": Distribution(None, "", (-math.inf, math.inf)),
    "normal": Distribution(normal, "sd", (-math.inf, math.inf)),
    "log-normal": Distribution(log_normal, "log_sd", (0.0, math.inf)),
    "logit-normal": Distribution(logit_normal, "logit_sd", (0.0, 1.0)),
    "uniform": Distribution(uniform, "", (-math.inf, math.inf)),
}


def fields(name: str) -> tuple[str, ...]:
    """The numeric fields an entry of distribution ``name`` may hold besides ``distribution`` (and ``source``, the
    citation of its spread, or why it has none)."""
    if name == "fixed":
        return ()
    if name == "uniform":
        return BOUNDS
    return ("median", DISTRIBUTIONS[name].spread, *BOUNDS)


ENTRY_FIELDS = {"distribution", "median", "sd", "log_sd", "logit_sd", *BOUNDS, "source"}


def flatten(table, prefix: str = "") -> dict:
    """``{"brain": {"gamma0": {...}}}`` or ``{"brain.gamma0": {...}}`` -> ``{"brain.gamma0": {...}}``: a table
    holding an entry's field (``distribution``, ``median``, a spread, a bound, ``source``) is an entry."""
    flat = {}
    for key, value in table.items():
        if isinstance(value, dict) and value and not ENTRY_FIELDS & set(value):
            flat.update(flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def checked_table(table, base: dict | None = None) -> dict:
    """The ``[population]`` table as ``{key: entry}`` over the entries of ``base`` (each entry's fields merged over
    its entry there: a sweep point's ``population.brain.gamma0.logit_sd``), each entry checked on its own (a known
    distribution, known fields, finite numbers, a spread >= 0, low < high, a uniform's two bounds); ConfigError
    naming the entry. What depends on the configuration (the key, the median, the bounds around it)
    :func:`check_entry` tests."""
    if not isinstance(table, dict):
        raise ConfigError("config key population must be a table of parameter keys, each "
                          "{distribution = ..., ...}")
    entries = dict(base or {})
    for key, entry in flatten(table).items():
        where = f"population.{key}"
        if isinstance(entry, dict) and key in entries:
            entry = {**entries[key], **entry}
        if not _KEY.fullmatch(key):
            raise ConfigError(f"{where}: name a configuration key as table.key (e.g. \"brain.gamma0\")")
        if not isinstance(entry, dict):
            raise ConfigError(f"{where} must be a table {{distribution = ..., ...}}, got {entry!r}")
        name = entry.get("distribution")
        if name not in DISTRIBUTIONS:
            raise ConfigError(f"{where}.distribution = {name!r} is not one of {', '.join(DISTRIBUTIONS)}")
        for field, value in entry.items():
            if field == "distribution":
                continue
            if field == "source":
                if not isinstance(value, str):
                    raise ConfigError(f"{where}.source must be text (the spread's citation), got {value!r}")
                continue
            if field not in fields(name):
                allowed = ", ".join(fields(name)) or "no other field"
                raise ConfigError(f"{where}: a {name} distribution takes {allowed}, not {field!r}")
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(f"{where}.{field} = {value!r} must be a finite number")
        spread = DISTRIBUTIONS[name].spread
        if spread and spread not in entry:
            raise ConfigError(f"{where}: a {name} distribution needs {spread} (its spread)")
        if spread and entry[spread] < 0:
            raise ConfigError(f"{where}.{spread} = {entry[spread]!r} is a spread: it must be >= 0")
        if name == "uniform" and not all(bound in entry for bound in BOUNDS):
            raise ConfigError(f"{where}: a uniform distribution needs low and high")
        if all(bound in entry for bound in BOUNDS) and not entry["low"] < entry["high"]:
            raise ConfigError(f"{where}: low = {entry['low']!r} must be below high = {entry['high']!r}")
        entries[key] = {field: (value if field in ("distribution", "source") else float(value))
                        for field, value in entry.items()}
    return entries


def configured_value(config: dict, key: str):
    """The key's value in ``config`` (None when it has none)."""
    table, _, name = key.partition(".")
    return config.get(table, {}).get(name) if isinstance(config.get(table), dict) else None


def median_of(entry: dict, config: dict, key: str) -> float:
    """The entry's median: a uniform's midpoint, else its ``median`` or the key's configured value."""
    if entry["distribution"] == "uniform":
        return 0.5 * (entry["low"] + entry["high"])
    return float(entry.get("median", configured_value(config, key)))


def spread(entry: dict) -> bool:
    """Whether the entry varies between participants (a fixed one, or a spread of 0, does not)."""
    name = entry["distribution"]
    return name == "uniform" or (name != "fixed" and entry[DISTRIBUTIONS[name].spread] > 0)


def check_entry(key: str, entry: dict, config: dict, declared: tuple | None) -> None:
    """What the configuration decides about one entry: a median within the distribution's support and within the
    bounds, bounds within the support, and the draws within the range the parameter's component declares
    (``declared``: (path, min, max, unit), or None). ConfigError naming the entry."""
    where, name = f"population.{key}", entry["distribution"]
    if name == "fixed":  # the key's own value, whatever it is (inf: body.release_time's never)
        return
    median = median_of(entry, config, key)
    low_support, high_support = DISTRIBUTIONS[name].support
    if name != "uniform" and not low_support < median < high_support or not math.isfinite(median):
        raise ConfigError(f"{where}: the median {median!r} lies outside a {name} distribution's values "
                          f"({low_support:g}, {high_support:g})")
    low, high = entry.get("low", low_support), entry.get("high", high_support)
    if name != "uniform" and not low <= median <= high:
        raise ConfigError(f"{where}: the bounds [{low:g}, {high:g}] exclude the median {median:g}")
    if low < low_support or high > high_support:
        raise ConfigError(f"{where}: the bounds [{low:g}, {high:g}] reach outside a {name} distribution's values "
                          f"({low_support:g}, {high_support:g})")
    if declared is None or not spread(entry):
        return
    path, minimum, maximum, unit = declared
    # an open end of the support (a log-normal's 0) is no draw; the draws themselves are checked with the rest
    below = minimum is not None and low < minimum and ("low" in entry or math.isinf(low))
    above = maximum is not None and high > maximum and ("high" in entry or math.isinf(high))
    if below or above:
        shown = f"[{minimum if minimum is not None else -math.inf:g}, {maximum if maximum is not None else math.inf:g}]"
        raise ConfigError(f"{where}: a {name} distribution on [{low:g}, {high:g}] draws values outside {path}'s "
                          f"range {shown}{'' if unit in ('', '1') else ' ' + unit}; give low and high within it")


def participant_seed(master_seed: int, index: int) -> int:
    """A stable 63-bit seed per participant: a hash of the master seed and the participant's index (the trial
    index of every cell), independent of the cell, so one participant runs every cell."""
    digest = hashlib.sha256(f"{master_seed}/participant/{index}".encode()).digest()
    return int.from_bytes(digest[:8], "little") >> 1


def key_code(key: str) -> int:
    """A stable 32-bit number per key: its stream within the participant's."""
    return int.from_bytes(hashlib.sha256(key.encode()).digest()[:4], "little")


def variate(seed: int, key: str) -> float:
    """The participant's uniform variate for ``key``, strictly inside (0, 1): 53 random bits, offset by half."""
    bits = np.random.default_rng([seed, POPULATION_STREAM, key_code(key)]).integers(0, 2**53)
    return (float(bits) + 0.5) / 2.0**53


def quantile(entry: dict, median: float, u):
    """The value at probability ``u`` (scalar or array in (0, 1)) of the entry's distribution, truncated to its
    bounds: u mapped onto [F(low), F(high)], then through the standard normal's quantile and the distribution's
    map (inverse transform sampling)."""
    from scipy import special

    name = entry["distribution"]
    if name == "uniform":
        return entry["low"] + (entry["high"] - entry["low"]) * np.asarray(u, dtype=float)
    forward, inverse = DISTRIBUTIONS[name].transform(median, entry[DISTRIBUTIONS[name].spread])
    low, high = DISTRIBUTIONS[name].support
    with np.errstate(divide="ignore"):
        lower = special.ndtr(inverse(entry["low"])) if "low" in entry and entry["low"] > low else 0.0
        upper = special.ndtr(inverse(entry["high"])) if "high" in entry and entry["high"] < high else 1.0
    value = forward(special.ndtri(lower + (upper - lower) * np.asarray(u, dtype=float)))
    return np.clip(value, entry.get("low", -math.inf), entry.get("high", math.inf))  # rounding at a bound


def entries(config: dict) -> dict:
    """The configuration's population entries (``{}``: none configured)."""
    return config.get("population", {})


def draw(config: dict, master_seed: int, index: int, key: str) -> float:
    """Participant ``index``'s value of ``key`` under master seed ``master_seed``."""
    entry = entries(config)[key]
    median = median_of(entry, config, key)
    if not spread(entry):
        return median
    return drawn(master_seed, index, key, tuple(sorted(entry.items())), median)


@functools.lru_cache(maxsize=2**16)
def drawn(master_seed: int, index: int, key: str, entry: tuple, median: float) -> float:
    """:func:`draw` of a varying entry (``entry``: its items), kept: a participant is drawn once, not again for each
    of its cells and each time a lockstep batch plans the protocol (three times as it is built)."""
    return float(quantile(dict(entry), median, variate(participant_seed(master_seed, index), key)))


def participant(config: dict, index: int) -> tuple:
    """Participant ``index``'s own values, ``((key, value), ...)`` in key order, of the keys that vary between
    participants (``Trial.overrides``); () for none."""
    seed = config["experiment"]["seed"]
    return tuple((key, draw(config, seed, index, key)) for key in sorted(entries(config))
                 if spread(entries(config)[key]) or entries(config)[key].get("median") is not None)


def cohort(config: dict, indices) -> dict[str, np.ndarray]:
    """Every population key's value for participants ``indices`` (key order): ``{key: (len(indices),) array}``."""
    seed = config["experiment"]["seed"]
    return {key: np.array([draw(config, seed, int(index), key) for index in indices], dtype=float)
            for key in sorted(entries(config))}


def varies(config: dict) -> bool:
    """Whether the configuration's population has a spread (a cohort of different participants)."""
    return any(spread(entry) for entry in entries(config).values())


def refuse_in(config: dict, command: str) -> None:
    """A ConfigError when ``config`` has a population and ``command`` (a task whose trials are not the protocol's
    participants: the reach, the moving hand) would run without it."""
    if entries(config):
        raise ConfigError(f"{command} runs no [population] (its trials are not the protocol's participants); remove "
                          "the table")
