"""Each generated table of docs/: a function of the code that returns its Markdown.

A column without a meaning in :data:`MEANINGS` raises, so a new output column cannot reach a run
without reaching docs/configuration.md too.
"""
from __future__ import annotations

import math
import re
from importlib import resources
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from rhi.components.body.contract import BODY_CONTRACT
from rhi.master.reference.imports import floor_imports

# What every output column means (the names say their units; none: dimensionless).
MEANINGS = {
    "decoder": "visual decoder: conv or vae",
    "condition": "rubber-hand position: left, center, right (or a condition the configuration adds)",
    "stimulation": "sync or async (or a stimulation the configuration adds)",
    "trial": "trial index within its cell",
    "seed": "the trial's seed (a hash of the master seed, condition, stimulation and index)",
    "step": "communication step, 0 = the initial state",
    "time_s": "time of the row",
    "n_trials": "trials of the cell that finished (0: every one failed, the statistics are empty)",
    "drift_cm": "perceived minus real hand x; negative = to the left",
    "force_x_n": "horizontal force the held arm exerts at the hand",
    "force_y_n": "force along y at the hand",
    "gamma": "belief in a common cause of the seen and the felt touch",
    "mu_shoulder_deg": "belief mu, shoulder", "mu_elbow_deg": "belief mu, elbow",
    "s_p_shoulder_deg": "sensed shoulder angle s_p", "s_p_elbow_deg": "sensed elbow angle s_p",
    "action_shoulder_deg_s": "action a (commanded joint velocity), shoulder",
    "action_elbow_deg_s": "action a, elbow",
    "action_rate_shoulder_deg_s2": "a_dot = -(s_p - mu)/Sigma_p (paper eq. 7), shoulder",
    "action_rate_elbow_deg_s2": "a_dot, elbow",
    "action_accel_x_m_s2": "the paper's action measure (Fig. 3 d-f): horizontal hand acceleration J a_dot",
    "visual_time_s": "time of the last observed visual event (-inf before any)",
    "tactile_time_s": "time of the last observed tactile event (-inf before any)",
    "visual_error": ("1/2 e^T e (256^2/HW) / Sigma_v, e = s_v - g(mu); NaN when the model reads no pixel term "
                     "(no decoder runs)"),
    "free_energy": "sum (s_p - mu)^2/(2 Sigma_p) + gamma visual_error, at the step's starting mu",
    "ball_x_m": "ball position x", "ball_y_m": "ball position y",
    "drift_cm_mean": "final drift, mean over the cell's trials", "drift_cm_sd": "its sample sd (ddof 1)",
    "force_n_mean": "final force_x_n, mean", "force_n_sd": "its sample sd",
    "gamma_final_mean": "final gamma, mean", "gamma_final_sd": "its sample sd",
    "action_accel_mean_x_m_s2_mean": "action_accel_x_m_s2 averaged over the trial's steps, mean over trials",
    "action_accel_mean_x_m_s2_sd": "its sample sd",
    "action_accel_x_m_s2_mean": "final action_accel_x_m_s2, mean over trials", "action_accel_x_m_s2_sd": "its sample sd",
    "id": "the trial's ID (a hash of everything that decides its result)", "point": "the sweep point's index",
    "KEY": "one column per swept key: the point's value",
    "n_failed": "trials of the cell that failed", "status": "ok or failed",
    "force_n": "final force_x_n", "gamma_final": "final gamma",
    "elapsed_s": "the trial's chunk's wall time", "error": "a failed trial's error",
    "x": "the swept quantity: delay_s, distance_cm or time_s",
    "drift_half_time_s_mean": "when the drift first reaches half its final value, mean",
    "drift_half_time_s_sd": "its sample sd", "drift_relative": "mean drift relative to the protocol's reference",
    "model": "the model: a name or FILE.py:Class (--model)",
    "drift_half_decay_s_mean": "seconds from the last touch until the drift falls to half its value then, mean",
    "drift_half_decay_s_sd": "its sample sd",
    "drift_cm_median": "final drift, median over the cell's trials (participants)",
    "drift_cm_q25": "its 25th percentile", "drift_cm_q75": "its 75th percentile",
    "drift_half_time_s_median": "drift_half_time_s, median", "drift_half_time_s_q25": "its 25th percentile",
    "drift_half_time_s_q75": "its 75th percentile",
    "drift_half_decay_s_median": "drift_half_decay_s, median", "drift_half_decay_s_q25": "its 25th percentile",
    "drift_half_decay_s_q75": "its 75th percentile",
}


def markdown(header: list[str], rows: list[list]) -> str:
    """A Markdown table of ``header`` and ``rows`` (each cell as ``str``, its ``|`` escaped)."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(str(cell).replace("|", "\\|") for cell in row) + " |"
                              for row in rows])


def columns(names: list[str]) -> str:
    """The column-and-meaning table of output columns ``names``; KeyError if one is not in :data:`MEANINGS`."""
    missing = [name for name in names if not MEANINGS.get(name)]
    if missing:
        raise KeyError(f"master/reference/tables.py MEANINGS lacks the output columns {', '.join(missing)}")
    return markdown(["column", "meaning"], [[f"`{name}`", MEANINGS[name]] for name in names])


def summary_columns() -> str:
    """summary.csv's columns and their meanings."""
    from rhi.master.outputs.tables import SUMMARY_COLUMNS
    return columns(SUMMARY_COLUMNS)


def trials_columns() -> str:
    """trials.csv's header, from the code that writes it, run on a recording of one step and one trial."""
    from rhi.master.tasks.illusion.measures import measures
    from rhi.master.outputs.tables import trials_csv

    pairs = ("brain.mu", "brain.action_rate", "stimulus.ball")

    class Recording(dict):
        def __missing__(self, path):
            return np.zeros((2, 1, 2) if path in pairs else (2, 1))

    per_step = measures(SimpleNamespace(values=Recording()))
    trial = SimpleNamespace(decoder="conv", condition="left", stimulation="sync", index=0, seed=0)
    return columns(trials_csv([trial], np.zeros(2), per_step).splitlines()[0].split(","))


def sweep_columns() -> str:
    """A sweep folder's ``index.csv`` and ``summary.csv`` columns and their meanings, from the code that writes them."""
    from rhi.master.sweeps import tables
    sweep = SimpleNamespace(keys=["KEY"], trials=[], points=[])
    index = tables.index_rows(sweep, {}).splitlines()[0].split(",")
    summary = tables.summary_csv(sweep, list(tables.MEASURES), []).splitlines()[0].split(",")
    return "`index.csv`:\n\n" + columns(index) + "\n\n`summary.csv`:\n\n" + columns(summary)


def phenomenon_columns() -> str:
    """A phenomenon's table columns and their meanings (the swept quantity as ``x``)."""
    from rhi.master.phenomena.report import PHENOMENA, table
    model, _, *rest = table(next(iter(PHENOMENA.values())), []).splitlines()[0].split(",")  # model, x, ...
    return columns([model, "x", *rest])


def commented_keys(name: str) -> list[tuple[str, str, str]]:
    """(dotted key, value as written, comment) for every key of the shipped ``master/NAME``
    (``config/defaults.toml``, ``models/ownership.toml``); a key without a comment of its own takes its table's;
    [quick]'s entries are keys whole."""
    rows, table, table_comment, last = [], "", [""], None
    text = resources.files("rhi.master").joinpath(name).read_text()
    for line in text.splitlines():
        header = re.match(r"^\[([\w.]+)\]\s*(?:#\s*(.*))?$", line)
        entry = re.match(r"^([\w\"-]+)\s*=\s*(.*?)\s*(?:#\s*(.*))?$", line)
        more = re.match(r"^\s+#\s*(.*)$", line)
        if header:
            table, table_comment = header.group(1), [header.group(2) or ""]
            last = table_comment
        elif entry:
            rows.append([f"{table}.{entry.group(1)}", entry.group(2), entry.group(3) or None, table_comment])
            last = rows[-1] if entry.group(3) else None
        elif more and last is not None:
            if last is table_comment:
                last[0] += " " + more.group(1)
            else:
                last[2] += " " + more.group(1)
        else:
            last = None
    return [(key, value, comment or inherited[0]) for key, value, comment, inherited in rows]


def configuration_keys() -> str:
    """Every key of the shipped defaults.toml: its default and its comment."""
    return markdown(["key", "default", "meaning"],
                    [[f"`{key}`", f"`{value}`", comment] for key, value, comment in commented_keys("config/defaults.toml")])


def paper_preset() -> str:
    """Every key of the shipped paper preset (``master/config/presets/paper_256.toml``): its value there, its
    default, and why."""
    defaults = {key: value for key, value, _ in commented_keys("config/defaults.toml")}
    return markdown(["key", "paper", "default", "why"],
                    [[f"`{key}`", f"`{value}`", f"`{defaults[key]}`", why]
                     for key, value, why in commented_keys("config/presets/paper_256.toml")])


def number(value, integer: bool = False) -> str:
    """``value`` as a table shows it: whole numbers (and any, with ``integer``) without a decimal point, others
    as ``%g``; None and NaN as ``NaN``, infinities as ``∞`` and ``−∞``.
    """
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "NaN"
    if math.isinf(value):
        return "∞" if value > 0 else "−∞"
    return str(int(value)) if integer or float(value).is_integer() else f"{value:g}"


def port_rows(variables) -> list[list[str]]:
    """One row per variable: port, causality, type, unit, range, start (none for an output), meaning."""
    rows = []
    for v in variables:
        integer = v.type == "Integer"
        low = "−∞" if v.min is None else number(v.min, integer)
        high = "∞" if v.max is None else number(v.max, integer)
        start = "" if v.causality == "output" else (str(v.start).lower() if v.type == "Boolean"
                                                   else number(v.start, integer))
        bounds = "" if v.type == "Boolean" else f"[{low}, {high}]"
        rows.append([f"`{v.name}`", v.causality, v.type, v.unit or "1", bounds, start, v.description])
    return rows


PORTS = ["port", "causality", "type", "unit", "range", "start", "meaning"]


def agent_ports(task: str = "illusion") -> str:
    """The ports of ``task``'s agent (:func:`rhi.master.tasks.exportable`), under the task's default configuration."""
    from rhi.master.decoders.cache import checkpoint_path
    from rhi.master.export.agent_fmu import make_agent
    from rhi.master.tasks import TASKS

    defaults = TASKS[task].load(None, {}, False)
    agent = make_agent(checkpoint_path("conv", defaults, must_exist=True), "conv", defaults, task)
    return markdown(PORTS, port_rows(agent.variables.values()))


def body_ports() -> str:
    """The pymunk plant's ports, with whether the body contract requires each."""
    from rhi.components.body.plant import ArmPlant
    required = {v.name for v in BODY_CONTRACT}
    variables = list(ArmPlant().variables.values())
    return markdown(PORTS[:-1] + ["required", "meaning"],
                    [row[:-1] + ["yes" if v.name in required else "", row[-1]]
                     for v, row in zip(variables, port_rows(variables))])


def c_body_fmi3_ports() -> str:
    """The C body's FMI 3.0 variables (rhi.master.export.c_body.ARRAYS over the Python arm's declarations), each with
    the FMI 2.0 ports it carries."""
    from rhi.components.fmi_export.description_fmi3 import TYPES, layout
    from rhi.master.export.c_body import ARRAYS, declared_body

    body = declared_body()
    rows = [["`time`", "Float64", "", str(len(body.variables)), "independent", "s", ""]]
    for name, reference, group, _ in layout(body, ARRAYS):
        v = group[0]
        rows.append([f"`{name}`", TYPES[v.type], f"[{len(group)}]" if len(group) > 1 else "", str(reference),
                     v.causality, v.unit or "1", ", ".join(f"`{m.name}`" for m in group)])
    return markdown(["variable", "type", "dimension", "value reference", "causality", "unit", "FMI 2.0 ports"], rows)


def worker_command() -> str:
    """The `dask worker` command with :data:`rhi.master.sweeps.runner.WORKER_SETTINGS` as environment variables."""
    from rhi.master.sweeps.runner import WORKER_SETTINGS
    settings = [f"DASK_{key.upper().replace('.', '__').replace('-', '_')}={value}"
                for key, value in WORKER_SETTINGS.items()]
    return "\n".join(["```", *(f"{setting} \\" for setting in settings),
                      ".venv/bin/dask worker tcp://SCHEDULER-HOST:8786 --nworkers $(nproc) --nthreads 1", "```"])


def model_columns() -> str:
    """The columns each built-in model adds to trials.csv (:attr:`rhi.master.models.base.Model.measures`), with the
    description of the brain output each records."""
    from rhi.master import models

    rows = []
    for name in models.BUILT_IN:
        model = models.get(name)
        described = model.brain().variables if model.measures else {}
        for column, path in model.measures.items():
            variable = described[path.partition(".")[2]]
            rows.append([f"`{name}`", f"`{column}`", f"{variable.description} ({variable.unit})"])
    return markdown(["model", "column", "meaning (unit)"], rows)


def ownership_constants() -> str:
    """The ownership model's constants: each brain parameter, the key it comes from, its value (a derived one
    computed by the code that derives it) and its source, from master/models/ownership.toml's comments; the free
    parameters with their prior ranges (rhi.master.models.ownership.FREE_PARAMETERS)."""
    from rhi.components.body.kinematics import FOREARM, UPPER_ARM
    from rhi.components.brain.ownership_inference import peripersonal_sd_from_boundary
    from rhi.master import config as configuration
    from rhi.master.models.ownership import DERIVED_FROM, FREE_PARAMETERS, OWN_SOURCES, SHARED_KEYS, fitted_values

    config = configuration.load(model_name="ownership")
    comments = {key: comment for key, _, comment in commented_keys("models/ownership.toml")}
    estimates = fitted_values(Path(__file__).resolve().parents[2])

    def value(key):
        table, _, name = key.partition(".")
        return config[table][name]

    reach = UPPER_ARM + FOREARM
    derivations = {  # parameter: (how, value), each computed by the function the model derives it with
        "brain.peripersonal_sd": (f"and the reach L = {reach:.4f} m",
                                  peripersonal_sd_from_boundary(value(DERIVED_FROM["brain.peripersonal_sd"]), reach))}
    body = {"brain.upper_arm_length": UPPER_ARM, "brain.forearm_length": FOREARM}
    rows = []
    for parameter, source in OWN_SOURCES.items():
        name = f"`{parameter.partition('.')[2]}`"
        if source.startswith("per trial:"):
            continue
        if parameter in DERIVED_FROM:
            key = DERIVED_FROM[parameter]
            derived = derivations[parameter]
            rows.append([name, f"`{key}` {derived[0]}", f"{derived[1]:.4f}", f"derived: {comments[key]}"])
        elif source.startswith("derived:"):
            rows.append([name, "the body", f"{body[parameter]:g}", source.partition(":")[2].strip()])
        elif source in FREE_PARAMETERS:
            prior, low, high = FREE_PARAMETERS[source]
            shown_low = f"1/{1 / low:g}" if prior == "log-uniform" else f"{low:g}"
            fitted = estimates.get(source)
            how = (f"fitted: {fitted['rule']} (marginal 90 %: {fitted['q05']:.2g}-{fitted['q95']:.2g}) of "
                   f"`{fitted['folder']}/`"
                   if fitted else "free, **not fitted yet**: the value is a start, not a result")
            rows.append([name, f"`{source}`", f"{value(source):g}", f"{how}, prior {prior} on [{shown_low}, {high:g}]"])
        else:
            rows.append([name, f"`{source}`", f"{value(source):g}", comments.get(source) or SHARED_KEYS[source]])
    return markdown(["parameter", "from", "value", "source or derivation"], rows)


def population_spreads() -> str:
    """Every shipped population (docs/population/*.toml; one named after a model is that model's): each parameter's
    distribution, median, spread, bounds and the source of its spread (the entry's ``source``), as the configuration
    reads them."""
    from rhi.master import config as configuration
    from rhi.master import models
    from rhi.master.config import population

    rows = []
    for path in sorted((Path(__file__).resolve().parents[2] / "docs" / "population").glob("*.toml")):
        config = configuration.load(path, model_name=path.stem if path.stem in models.names() else "paper")
        for key, entry in population.entries(config).items():
            name = entry["distribution"]
            spread = population.DISTRIBUTIONS[name].spread
            low, high = entry.get("low"), entry.get("high")
            bounds = (f"[{low:g}, {high:g}]" if low is not None and high is not None else f">= {low:g}"
                      if low is not None else f"<= {high:g}" if high is not None else "")
            rows.append([f"`docs/population/{path.name}`", f"`{key}`", name,
                         f"{population.median_of(entry, config, key):g}",
                         f"{spread} = {entry[spread]:g}" if spread else "", bounds, entry.get("source", "")])
    return markdown(["file", "key", "distribution", "median", "spread", "bounds", "source"], rows)


def fmi_compat() -> str:
    """docs/fmi.md's compatibility matrix, from the results ``python -m rhi.master.export.compat`` measured."""
    from rhi.master.export.compat import stored_table

    return stored_table()


TABLES = {"population-spreads": population_spreads, "model-columns": model_columns, "ownership-constants": ownership_constants, "configuration-keys": configuration_keys, "paper-preset": paper_preset, "summary-columns": summary_columns,
          "trials-columns": trials_columns, "sweep-columns": sweep_columns, "phenomenon-columns": phenomenon_columns,
          "agent-ports": agent_ports, "reach-agent-ports": lambda: agent_ports("reach"), "body-ports": body_ports,
          "c-body-fmi3-ports": c_body_fmi3_ports, "fmi-compat": fmi_compat, "worker-command": worker_command,
          "floor-imports": floor_imports}
