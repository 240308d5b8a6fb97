"""Configuration: shipped TOML defaults, a preset over them, a user's TOML file, command-line overrides last.

A preset (``--preset paper``) is a shipped TOML file in ``master/config/presets/`` (``paper_256.toml``)
holding only the keys it changes; it is merged like the ``[quick]`` table, with the same checks.

Every key a user may set exists in ``defaults.toml``; a key that does not is an
error naming it and suggesting the closest one. Values are type-checked against
the default's type.
"""
from __future__ import annotations

import copy
import difflib
import math
import os
import tomllib
from importlib import resources
from pathlib import Path

from rhi.components.vision.limits import MIN_VISUAL_VARIANCE
from rhi.master import models
from rhi.master.config import bodies, population, schedules
from rhi.master.cosim import ConfigError

OPEN_TABLES = ("conditions", "stimulations")  # users may add entries here (a new condition, say)
LISTS = ("decoders", "conditions", "stimulations")  # experiment.* lists: non-empty, no entry twice
SCHEMES = ("gauss-seidel", "jacobi")
MAX_RESOLUTION = 1024  # px; the paper's decoders work at 256
PRESETS = {"paper": "paper_256.toml"}  # --preset NAME merges master/config/presets/FILE over the defaults


def defaults() -> dict:
    """The shipped defaults, ``master/config/defaults.toml`` (every task's), read afresh (its ``[quick]`` table
    included)."""
    with resources.files("rhi.master.config").joinpath("defaults.toml").open("rb") as file:
        return tomllib.load(file)


def preset(name: str) -> dict:
    """The shipped preset ``name`` (``master/config/presets/``, :data:`PRESETS`): the keys it changes; ConfigError
    if unknown."""
    if name not in PRESETS:
        raise ConfigError(f"preset {name!r} is unknown; choose one of {', '.join(PRESETS)}")
    with resources.files("rhi.master.config").joinpath("presets", PRESETS[name]).open("rb") as file:
        return tomllib.load(file)


def with_model(config: dict, name: str) -> dict:
    """``config`` with the model ``name`` (a registered name or ``file.py:Class``, :func:`rhi.master.models.get`)
    merged over it: its new tables (``[model]``, ``[causal]``) added, its keys in existing tables merged."""
    shipped = models.get(name).settings()
    added = {table: values for table, values in shipped.items() if table not in config}
    return merge({**config, **copy.deepcopy(added)},
                 {table: values for table, values in shipped.items() if table not in added})


MAX_CONFIG_BYTES = 2**20  # a configuration or sweep file; the shipped ones are a few KiB
MAX_DEPTH = 16  # tables and arrays within each other; the shipped files nest three deep
# torch threads (train.threads): twice the hardware threads of the largest common server (two 128-core CPUs
# with 2-way SMT: 512); a thread count is a setting that makes bits, not a measure of the machine.
MAX_THREADS = 1024
def file_problem(path, what: str = "checkpoint file") -> str | None:
    """Why ``path`` cannot be read as a ``what``, by its kind before it is opened (a FIFO would wait for a writer
    forever, a device would never end): "does not exist", "is a folder, not a ...", "is not a regular file (...)";
    None for a regular file (a link to one counts)."""
    import stat

    try:
        kind = os.stat(path).st_mode
    except FileNotFoundError:
        return "does not exist"
    except OSError as error:
        return f"cannot be read: {error.strerror or error}"
    if stat.S_ISDIR(kind):
        return f"is a folder, not a {what}"
    if not stat.S_ISREG(kind):
        return "is not a regular file (a FIFO, a device or a socket)"
    return None


INFINITE_KEYS = ("brain.spatial_sd", "brain.action_time_constant", "body.release_time",  # inf: the paper's model
                 "stimulus.stroke_duration", "stimulus.stop_time")  # inf: the whole period; the stroking never stops


def depth(value) -> int:
    """How deep tables and arrays nest in ``value`` (a scalar: 0), counted without recursion."""
    deepest, stack = 0, [(value, 0)]
    while stack:
        item, level = stack.pop()
        if isinstance(item, (dict, list)):
            deepest = max(deepest, level + 1)
            stack.extend((child, level + 1) for child in (item.values() if isinstance(item, dict) else item))
    return deepest


def read_toml(path: str | Path) -> dict:
    """The TOML file at ``path``: a regular file of at most MAX_CONFIG_BYTES, nested at most MAX_DEPTH deep."""
    try:
        if Path(path).exists() and not Path(path).is_dir() and not Path(path).is_file():
            raise ConfigError(f"config file {path} is not a regular file")
        with open(path, "rb") as file:
            data = file.read(MAX_CONFIG_BYTES + 1)
        if len(data) > MAX_CONFIG_BYTES:
            raise ConfigError(f"config file {path} is over the limit of {MAX_CONFIG_BYTES} bytes")
        loaded = tomllib.loads(data.decode("utf-8"))
        if depth(loaded) > MAX_DEPTH:
            raise ConfigError(f"config file {path} nests tables and arrays over {MAX_DEPTH} deep")
        return loaded
    except RecursionError:
        raise ConfigError(f"config file {path} nests tables and arrays over {MAX_DEPTH} deep") from None
    except FileNotFoundError:
        raise ConfigError(f"config file {path} does not exist") from None
    except IsADirectoryError:
        raise ConfigError(f"config file {path} is a folder, not a TOML file") from None
    except UnicodeDecodeError as error:
        raise ConfigError(f"config file {path} is not UTF-8 text (byte {error.object[error.start]:#04x} at "
                          f"position {error.start}); TOML files are UTF-8") from None
    except OSError as error:
        raise ConfigError(f"config file {path} cannot be read: {error.strerror or error}") from None
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"config file {path} cannot be read: {error}") from None


def unknown_key(path: str, known, kind: str = "config") -> ConfigError:
    """The error for an unknown key: ``unknown config key brain.gama0 (did you mean brain.gamma0?)``.

    path: the dotted key as written; known: the keys valid beside its last part; kind: what
    the key belongs to ("config", "sweep"). The suggestion is the closest known key, if any.
    """
    where, _, key = path.rpartition(".")
    close = difflib.get_close_matches(key, list(known), n=1)
    hint = f" (did you mean {where + '.' if where else ''}{close[0]}?)" if close else ""
    return ConfigError(f"unknown {kind} key {path}{hint}")


def merge(base: dict, overrides: dict, where: str = "") -> dict:
    """``base`` updated by ``overrides``; unknown keys and wrong types are ConfigErrors naming the key."""
    merged = copy.deepcopy(base)
    for key, value in overrides.items():
        path = f"{where}{key}"
        if key == "population" and not where:  # participants' distributions: no defaults, each entry checked alone
            merged[key] = population.checked_table(value, base.get(key, {}))
            continue
        if key not in base and "." in key and key.split(".")[0] in base:  # "a.b" = 1: the documented dotted form
            merged = merge(merged, nest({key: value}), where)
            continue
        if key not in base:
            if where.rstrip(".") in OPEN_TABLES:  # a new entry: checked against an existing one's keys and types
                template = next(iter(base.values()), None)
                if isinstance(template, dict):
                    if not isinstance(value, dict):
                        raise ConfigError(f"config key {path} must be a table like {where}{next(iter(base))}")
                    merged[key] = merge(template, value, f"{path}.")
                else:
                    merged[key] = check_type(path, value, template) if template is not None else copy.deepcopy(value)
                continue
            raise unknown_key(path, base)
        default = base[key]
        if isinstance(default, dict):
            if not isinstance(value, dict):
                raise ConfigError(f"config key {path} must be a table")
            merged[key] = merge(default, value, f"{path}.")
        else:
            merged[key] = check_type(path, value, default)
    return merged


def is_number(value) -> bool:
    """Whether ``value`` is an int or a float (TOML's numbers), not a Boolean."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def check_type(path: str, value, default):
    """``value`` of config key ``path`` checked against the type of its ``default``, and returned.

    A float default takes an int too (returned as a float) and must be finite (``inf`` only for ``INFINITE_KEYS``);
    numbers must be within ``2**63``; a default list of names takes only names. ConfigError otherwise."""
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, float):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        if ok and isinstance(value, int) and abs(value) > 2**63:
            raise ConfigError(f"config key {path} = {str(value)[:30]}... has {len(str(abs(value)))} digits; it must "
                              "be a number within about 9.2e18")
        value = float(value) if ok else value
        if ok and math.isinf(value) and path in INFINITE_KEYS:
            return value
        if ok and not math.isfinite(value):
            raise ConfigError(f"config key {path} = {value!r} must be a finite number")
    elif isinstance(default, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
        if ok and abs(value) > 2**63:
            raise ConfigError(f"config key {path} = {str(value)[:30]}... has {len(str(abs(value)))} digits; it must "
                              "be an integer within about 9.2e18")
    elif isinstance(default, list):
        ok = isinstance(value, list)
        if ok and default and all(isinstance(item, str) for item in default):
            ok = all(isinstance(item, str) for item in value)  # a list of names
        elif ok and default and all(is_number(item) for item in default):  # a list of numbers: each one finite
            if not all(is_number(item) and (abs(item) <= 2**63 if isinstance(item, int) else math.isfinite(item))
                       for item in value):
                raise ConfigError(f"config key {path} = {value!r} must be a list of finite numbers")
    else:
        ok = isinstance(value, type(default))
    if not ok:
        raise ConfigError(f"config key {path} = {value!r} must be a {type(default).__name__}")
    return value


def load(path: str | Path | None = None, overrides: dict | None = None, quick: bool = False,
         preset_name: str | None = None, model_name: str = "paper") -> dict:
    """The effective configuration: defaults, then ``[quick]`` if asked, then the preset named, then the
    model, then the file, then overrides.

    overrides: ``{"experiment.trials": 3, ...}`` from the command line.
    preset_name: a shipped preset (:data:`PRESETS`), e.g. ``"paper"``; None: none.
    model_name: a model, by name or ``file.py:Class`` (:func:`rhi.master.models.get`); ``paper`` (the default) adds
    nothing.
    """
    config = defaults()
    quick_values = config.pop("quick")
    if quick:
        config = merge(config, quick_values)
    if preset_name is not None:
        config = merge(config, preset(preset_name))
    config = with_model(config, model_name)
    if path is not None:
        config = merge(config, read_toml(path))
    config = merge(config, nest(overrides or {}))
    validate(config)
    return config


def nest(dotted: dict) -> dict:
    """``{"experiment.trials": 3}`` -> ``{"experiment": {"trials": 3}}``."""
    nested: dict = {}
    for path, value in dotted.items():
        *tables, key = path.split(".")
        cursor = nested
        for table in tables:
            cursor = cursor.setdefault(table, {})
        cursor[key] = value
    return nested


def validate(config: dict) -> None:
    """Ranges, lists and cross-references, and the memory a run would need; every message names the key."""
    experiment = config["experiment"]
    for key in ("trials", "steps", "resolution"):
        if experiment[key] < 1:
            raise ConfigError(f"experiment.{key} must be at least 1, got {experiment[key]}")
    if experiment["batch_trials"] < 0:
        raise ConfigError(f"experiment.batch_trials must be 0 (all of a decoder's trials) or more, got "
                          f"{experiment['batch_trials']}")
    if experiment["resolution"] < 8:
        raise ConfigError(f"experiment.resolution must be at least 8 pixels, got {experiment['resolution']}")
    if experiment["resolution"] > MAX_RESOLUTION:
        raise ConfigError(f"experiment.resolution must be at most {MAX_RESOLUTION} pixels, got "
                          f"{experiment['resolution']} (it would need about {size(memory_needed(config)[0])} "
                          "of memory)")
    if not experiment["step_size"] > 0:
        raise ConfigError(f"experiment.step_size must be positive, got {experiment['step_size']}")
    threads = config.get("train", {}).get("threads", 0)
    if not 0 <= threads <= MAX_THREADS:
        raise ConfigError(f"train.threads = {threads} must be 0 (every usable core) to {MAX_THREADS}")
    if experiment["scheme"] not in SCHEMES:
        raise ConfigError(f"experiment.scheme = {experiment['scheme']!r} is not one of {', '.join(SCHEMES)}")
    for key in LISTS:
        names = experiment[key]
        if not names:
            raise ConfigError(f"experiment.{key} is empty: name at least one")
        twice = sorted({str(name) for name in names if names.count(name) > 1})
        if twice:
            raise ConfigError(f"experiment.{key} lists {', '.join(twice)} more than once (each is run once, "
                              "with experiment.trials trials)")
    for decoder in experiment["decoders"]:
        if decoder not in ("conv", "vae"):
            raise ConfigError(f"experiment.decoders: unknown decoder {decoder!r} (conv or vae)")
    for table, names in (("conditions", experiment["conditions"]), ("stimulations", experiment["stimulations"])):
        for name in names:
            if name not in config[table]:
                raise ConfigError(f"experiment.{table}: {name!r} is not defined in [{table}]")
    for name, stimulation in config["stimulations"].items():
        low, high = stimulation.get("delay_min"), stimulation.get("delay_max")
        if not isinstance(low, (int, float)) or not isinstance(high, (int, float)) or not 0 <= low <= high:
            raise ConfigError(f"stimulations.{name}: need 0 <= delay_min <= delay_max, got {low!r}, {high!r}")
    bodies.check(config)
    schedules.check(config)  # blocks, touch, stroke duration, hidden rubber arms, probe times
    brain = config["brain"]
    if brain["proprioceptive_variance"] <= 0:
        raise ConfigError(f"brain.proprioceptive_variance must be positive, got {brain['proprioceptive_variance']}")
    if not brain["spatial_sd"] > 0:
        raise ConfigError(f"brain.spatial_sd must be positive (inf: the paper's model), got {brain['spatial_sd']}")
    if not brain["action_time_constant"] > 0:
        raise ConfigError(f"brain.action_time_constant must be positive (inf: the paper's action law), got "
                          f"{brain['action_time_constant']}")
    if not 0 < brain["gamma0"] <= 1:
        raise ConfigError(f"brain.gamma0 must be in (0, 1], got {brain['gamma0']}")
    for key in ("blur", "ball_radius"):
        if not config["camera"][key] >= 0:
            raise ConfigError(f"camera.{key} must be >= 0 m, got {config['camera'][key]}")
    if not config["decoder"]["visual_variance"] >= MIN_VISUAL_VARIANCE:  # the decoder's own range; NaN too
        raise ConfigError(f"decoder.visual_variance must be at least {MIN_VISUAL_VARIANCE:g} (the decoder's range), "
                          f"got {config['decoder']['visual_variance']}")
    for kind in ("conv", "vae"):  # a checkpoint named must be there, whether or not its decoder runs
        given = config["decoder"][f"{kind}_checkpoint"]
        problem = file_problem(given) if given else None
        if problem:
            raise ConfigError(f"decoder.{kind}_checkpoint: {given} {problem}")
    if not config["decoder"]["relinearise_tolerance"] >= 0:
        raise ConfigError(f"decoder.relinearise_tolerance must be >= 0 deg, got "
                          f"{config['decoder']['relinearise_tolerance']}")
    if not config["fmu"]["step_timeout_s"] >= 0:
        raise ConfigError(f"fmu.step_timeout_s must be >= 0 s (0: no limit), got {config['fmu']['step_timeout_s']}")
    needed, what = memory_needed(config)
    available = physical_memory()
    if available and needed > available:
        raise ConfigError(f"this run would need about {size(needed)} of memory ({what}), more than this machine's "
                          f"{size(available)}; lower experiment.resolution, experiment.steps or experiment.trials "
                          "(or train.samples)")
    from rhi.master.config.sources import check_parameters, check_population  # the components' own ranges

    check_population(config)
    check_parameters(config)  # with the population's draws of every participant the protocol plans
    check_step_size(config)  # after the components' ranges: it reads stimulus.period and [brain]


def check_step_size(config: dict) -> None:
    """experiment.step_size below each bound the configuration alone fixes, else a ConfigError naming it:
    at most one touch period (stimulus.period: a longer step would merge touches into one event), and
    below STABILITY_LIMIT times the belief's relaxation time (brain.proprioceptive_variance, the rate
    1/Sigma_p of paper eq. 6 with gamma = 0) and the action's time constant (brain.action_time_constant):
    explicit Euler on a decay of rate k is stable iff dt * k < 2 (the brain's own run-time check, which
    adds gamma's visual term)."""
    from rhi.components.brain.integrator import STABILITY_LIMIT

    step, brain = config["experiment"]["step_size"], config["brain"]
    if step > config["stimulus"]["period"]:
        raise ConfigError(f"experiment.step_size = {step:g} s is over the limit of stimulus.period = "
                          f"{config['stimulus']['period']:g} s (a longer step would merge touches)")
    for key, what in (("proprioceptive_variance", "the belief's relaxation time Sigma_p"),
                      ("action_time_constant", "the action's time constant")):
        if not step < STABILITY_LIMIT * brain[key]:
            raise ConfigError(f"experiment.step_size = {step:g} s must be below {STABILITY_LIMIT:g} x brain.{key} = "
                              f"{STABILITY_LIMIT * brain[key]:g} s ({what}: explicit Euler is stable iff dt * k < 2)")


# Bytes per trial and step of the recorded values, the tables built from them and trials.csv's rows, and
# bytes per image pixel in a lockstep batch (camera layers, the decoder's activations and tangents):
# generous upper bounds measured on the default run, to refuse a run that cannot fit, not to plan one.
BYTES_PER_TRIAL_STEP = 4096
BYTES_PER_BATCH_PIXEL = 256


def memory_needed(config: dict) -> tuple[int, str]:
    """About how many bytes of memory the run of ``config`` needs at its peak, and what dominates."""
    experiment, train = config["experiment"], config.get("train", {})
    pixels = experiment["resolution"] ** 2
    batch = len(experiment["conditions"]) * len(experiment["stimulations"]) * experiment["trials"]
    samples = int(train.get("samples", 0))
    decoders = len(experiment["decoders"])  # trained side by side, and their batches run side by side
    training = samples * pixels * 4 * 2 * decoders  # float32 images, and the batches cut from them
    recorded = (experiment["steps"] + 1) * batch * decoders * BYTES_PER_TRIAL_STEP
    images = batch * decoders * pixels * BYTES_PER_BATCH_PIXEL
    side = f"{experiment['resolution']} x {experiment['resolution']} px"
    return max((training, f"{samples} training images of {side}"),
               (recorded + images, f"{batch * len(experiment['decoders'])} trials of {experiment['steps']} steps "
                                   f"at {side}"))


def physical_memory() -> int:
    """Bytes of physical memory of this machine (0 if unknown)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, OSError, ValueError):
        return 0


def size(count: float) -> str:
    """Bytes in binary units: ``21.8 TiB``."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if count < 1024 or unit == "PiB":
            return f"{count:.1f} {unit}" if unit != "B" else f"{count:.0f} B"
        count /= 1024
    return f"{count:.1f} EiB"
