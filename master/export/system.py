"""``rhi export-system`` and ``rhi run-system``: the experiment as an SSP 1.0 package of agent and body FMUs.

The package (:func:`build_ssp`)::

    SystemStructure.ssd            the system: components agent and body, their connectors and connections
                                   (wiring.CONNECTIONS between body and brain), the step size and stop time
    resources/agent.fmu            the agent FMU (agent_fmu.py)
    resources/body.fmu             the body FMU (body.py / c_body.py, or the user's)
    resources/body.ssv             the body's parameters (the experiment's [body] keys it declares)
    resources/trials/<decoder>_<condition>_<stimulation>_<index>.ssv
                                   the agent's parameters for each trial of the protocol, its seed included

One parameter file per trial, not per condition: each trial has its own seed (protocol.trial_seed),
so a set per condition could not reproduce the experiment's trials; and libcosim applies only the
first parameter set bound to each component, so the SSD binds exactly one trial (the first of the
protocol, or the one asked for) and the others lie beside it for a tool to bind instead.

:func:`read_ssp` checks a package before it runs (one ConfigError naming the first problem: not a
zip, no SystemStructure.ssd, an FMU missing from the package or unusable, a connection or a parameter
naming a variable its FMU lacks or of the wrong causality or type). :func:`run_ssp` runs it, unchanged,
under FMPy's SSP master (``fmpy.ssp``) or libcosim (``libcosimpy``), in a child process
(``python -m master.export.ssp_runner``): the masters load the FMUs' native libraries, and a crash
there must not take the command down.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np

from components.body import kinematics
from master.cosim import ConfigError, SimulationError
from master.experiment import wiring
from master.experiment.protocol import Trial, plan
from master.export.agent import SEED, SEED_HIGH, SEED_LOW, agent_connections, exposed, split_seed
from master.outputs.files import atomic_write, check_output_file

NS = {"ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
      "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
      "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
      "osp": "https://opensimulationplatform.com/SSP/OSPAnnotations"}
SSD = "SystemStructure.ssd"
AGENT, BODY = "agent", "body"
SOURCES = {AGENT: "resources/agent.fmu", BODY: "resources/body.fmu"}
BODY_PARAMETERS = "resources/body.ssv"
TRIALS = "resources/trials"
FMU_TYPE = "application/x-fmu-sharedlibrary"
MASTERS = ("fmpy", "libcosim")
# run-system's communication steps: 2.8 h of the experiment's 0.01 s steps, its recorded connectors (about 20
# float64 each) 160 MB; far beyond the protocol's runs, far below what would exhaust memory or run for days.
MAX_STEPS = 1_000_000

for _prefix, _uri in NS.items():
    ET.register_namespace(_prefix, _uri)


def _q(tag: str) -> str:
    prefix, _, name = tag.partition(":")
    return f"{{{NS[prefix]}}}{name}"


def trial_name(trial: Trial) -> str:
    """``conv_left_sync_0``: a trial's parameter file, without folder and suffix."""
    return f"{trial.decoder}_{trial.condition}_{trial.stimulation}_{trial.index}"


def _format(kind: str, value) -> str:
    if kind == "Boolean":
        return "true" if bool(np.asarray(value).item()) else "false"
    if kind == "Integer":
        return str(int(np.asarray(value).item()))
    value = float(np.asarray(value).item())
    return {float("inf"): "INF", float("-inf"): "-INF"}.get(value, "NaN" if value != value else repr(value))


def _parse(kind: str, text: str):
    if kind == "Boolean":
        return text in ("true", "1")
    return int(text) if kind == "Integer" else float(text)


def parameter_set(name: str, values: dict[str, tuple[str, object]], starts: dict | None = None) -> bytes:
    """An SSV file: ``values`` is ``{parameter: (FMI type, value)}``, names relative to the component.

    A value that is not finite (``brain.spatial_sd = inf``, the paper's model) is left out: libcosim reads
    numbers with C++ streams, which do not take XML Schema's ``INF``, and refuses the whole package. It
    must then equal the FMU's own start value (``starts``: ``{parameter: start}``), which the FMU keeps.
    """
    root = ET.Element(_q("ssv:ParameterSet"), {"version": "1.0", "name": name})
    parameters = ET.SubElement(root, _q("ssv:Parameters"))
    for parameter, (kind, value) in values.items():
        if kind == "Real" and not np.isfinite(float(np.asarray(value).item())):
            start = (starts or {}).get(parameter)
            if start is None or float(start) != float(np.asarray(value).item()):
                raise ConfigError(f"{name}: {parameter} = {float(np.asarray(value).item())} cannot be written for "
                                  f"libcosim and differs from the FMU's start value {start}")
            continue
        element = ET.SubElement(parameters, _q("ssv:Parameter"), {"name": parameter})
        ET.SubElement(element, _q(f"ssv:{kind}"), {"value": _format(kind, value)})
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8") + b"\n"


def agent_parameters(trial: Trial, config: dict, declared: dict) -> dict:
    """The agent FMU's parameters for ``trial``: ``{name: (type, value)}`` from ``wiring.parameters``
    (the experiment's own values), the seed split into two Integers."""
    given = wiring.parameters([trial], config)
    values = {}
    for path, value in given.items():
        name = path.partition(".")[2]
        if path == SEED:
            low, high = split_seed(int(value[0]))
            values[SEED_LOW], values[SEED_HIGH] = ("Integer", low), ("Integer", high)
        elif exposed(path) and declared.get(name, ("",))[0] == "parameter":
            values[name] = (declared[name][1], np.asarray(value).reshape(-1)[0])
    return values


def body_parameters(trial: Trial, config: dict, declared: dict) -> dict:
    """The body FMU's parameters: the experiment's ``body.*`` values that the body declares (as run_batch)."""
    return {path.partition(".")[2]: (declared[path.partition(".")[2]][1], np.asarray(value).reshape(-1)[0])
            for path, value in wiring.parameters([trial], config).items()
            if path.startswith(BODY + ".") and path.partition(".")[2] in declared}


def declared_variables(fmu: str) -> dict[str, tuple[str, str]]:
    """``{name: (causality, FMI type)}`` of an FMU's scalar variables."""
    from fmpy import read_model_description
    return {v.name: (v.causality, v.type) for v in read_model_description(fmu, validate=False).modelVariables}


def start_values(fmu: str) -> dict[str, float]:
    """``{name: start}`` of an FMU's Real variables that have a start value."""
    from fmpy import read_model_description
    return {v.name: float(v.start) for v in read_model_description(fmu, validate=False).modelVariables
            if v.type == "Real" and v.start is not None}


def system_description(agent: dict, body: dict, bound: str, step_size: float, stop_time: float, name: str) -> bytes:
    """SystemStructure.ssd: the agent and body components (every input and output a connector), their
    connections (:func:`~master.export.agent.agent_connections`), the bound parameter files and the
    default experiment (libcosim's fixed-step algorithm annotation carries the step size)."""
    root = ET.Element(_q("ssd:SystemStructureDescription"), {"version": "1.0", "name": name, "generationTool": "rhi"})
    system = ET.SubElement(root, _q("ssd:System"), {"name": name, "description": "the rubber-hand agent and a body"})
    elements = ET.SubElement(system, _q("ssd:Elements"))
    for component, declared, parameters in ((AGENT, agent, f"{TRIALS}/{bound}.ssv"), (BODY, body, BODY_PARAMETERS)):
        element = ET.SubElement(elements, _q("ssd:Component"),
                                {"name": component, "type": FMU_TYPE, "source": SOURCES[component]})
        connectors = ET.SubElement(element, _q("ssd:Connectors"))
        for variable, (causality, kind) in declared.items():
            if causality in ("input", "output"):
                connector = ET.SubElement(connectors, _q("ssd:Connector"), {"name": variable, "kind": causality})
                ET.SubElement(connector, _q(f"ssc:{kind}"))
        bindings = ET.SubElement(element, _q("ssd:ParameterBindings"))
        ET.SubElement(bindings, _q("ssd:ParameterBinding"), {"type": "application/x-ssp-parameter-set",
                                                             "source": parameters})
    connections = ET.SubElement(system, _q("ssd:Connections"))
    for source, target in agent_connections(AGENT, BODY):
        (start, start_connector), (end, end_connector) = source.split("."), target.split(".")
        ET.SubElement(connections, _q("ssd:Connection"), {"startElement": start, "startConnector": start_connector,
                                                         "endElement": end, "endConnector": end_connector})
    experiment = ET.SubElement(root, _q("ssd:DefaultExperiment"), {"startTime": "0.0", "stopTime": repr(stop_time)})
    annotation = ET.SubElement(ET.SubElement(experiment, _q("ssd:Annotations")), _q("ssc:Annotation"),
                               {"type": "com.opensimulationplatform"})
    ET.SubElement(ET.SubElement(annotation, _q("osp:Algorithm")), _q("osp:FixedStepAlgorithm"),
                  {"baseStepSize": repr(step_size)})
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8") + b"\n"


def build_ssp(out, agent_fmu: str, body_fmu: str, config: dict, kind: str, bound: Trial | None = None) -> Path:
    """Write the SSP package at ``out`` (a path ending in .ssp), whole or not at all.

    Parameters
    ----------
    out : path
        The package to write.
    agent_fmu, body_fmu : str
        The FMUs (agent_fmu.build_agent_fmu; a body meeting the body contract).
    config : dict
        The configuration: the protocol (one parameter file per trial of decoder ``kind``), the step
        size and number of steps.
    kind : str
        The decoder the agent FMU carries.
    bound : Trial, optional
        The trial the SSD binds (default: the protocol's first of ``kind``).

    Returns
    -------
    Path
        ``out``.
    """
    out = check_output_file(out, "SSP file", ".ssp")
    trials = [t for t in plan(config) if t.decoder == kind]
    bound = bound or trials[0]
    if bound not in trials:
        trials.append(bound)
    agent, body, agent_starts = declared_variables(agent_fmu), declared_variables(body_fmu), start_values(agent_fmu)
    experiment = config["experiment"]
    ssd = system_description(agent, body, trial_name(bound), experiment["step_size"],
                             experiment["steps"] * experiment["step_size"], "RubberHandIllusion")

    def write(file):
        with zipfile.ZipFile(file, "w", zipfile.ZIP_DEFLATED) as archive:
            archive.writestr(SSD, ssd)
            archive.write(agent_fmu, SOURCES[AGENT])
            archive.write(body_fmu, SOURCES[BODY])
            archive.writestr(BODY_PARAMETERS, parameter_set("body", body_parameters(bound, config, body),
                                                            start_values(body_fmu)))
            for trial in trials:
                archive.writestr(f"{TRIALS}/{trial_name(trial)}.ssv", parameter_set(
                    trial_name(trial), agent_parameters(trial, config, agent), agent_starts))

    atomic_write(out, write)
    return out


# -- reading and checking a package -----------------------------------------------------------------------
@dataclass
class Package:
    """A checked SSP package.

    Attributes
    ----------
    path : str
        The .ssp file.
    components : dict
        ``name -> source`` (the FMU's path in the package), in the SSD's order.
    variables : dict
        ``name -> {variable: (causality, type)}`` of each component's FMU.
    connections : list
        ``(start element, start connector, end element, end connector)``.
    bindings : dict
        ``name -> [source, ...]``: each component's parameter files, in order (the first is what libcosim applies).
    parameters : list of str
        Every parameter file in the package.
    step_size, stop_time : float or None
        The default experiment's.
    """

    path: str
    components: dict = field(default_factory=dict)
    variables: dict = field(default_factory=dict)
    connections: list = field(default_factory=list)
    bindings: dict = field(default_factory=dict)
    parameters: list = field(default_factory=list)
    step_size: float | None = None
    stop_time: float | None = None


def _xml(archive: zipfile.ZipFile, member: str, where: str) -> ET.Element:
    try:
        return ET.fromstring(archive.read(member))
    except ET.ParseError as error:
        raise ConfigError(f"{where}: {member} is not valid XML ({error})") from None


def read_ssp(path) -> Package:
    """Read and check an SSP package before anything runs.

    Parameters
    ----------
    path : path
        The .ssp file.

    Returns
    -------
    Package
        What it holds.

    Raises
    ------
    ConfigError
        One line naming the first problem: no such file, not a zip, no SystemStructure.ssd, an FMU
        missing from the package or unusable, a parameter file missing, a connection to an element or
        variable that does not exist or of the wrong causality or type, a parameter its FMU lacks.
    """
    from components.archives import ArchiveError, check_archive
    from components.fmu import check_contract

    path, name = os.fspath(path), os.path.basename(os.fspath(path))
    if not os.path.isfile(path):
        raise ConfigError(f"{path} does not exist" if not os.path.exists(path) else f"{path} is not a file")
    if not zipfile.is_zipfile(path):
        raise ConfigError(f"{name} is not an SSP package: it is not a zip archive")
    try:
        check_archive(path)
    except ArchiveError as error:
        raise ConfigError(str(error)) from None
    package = Package(path)
    with zipfile.ZipFile(path) as archive, tempfile.TemporaryDirectory(prefix="rhi_ssp_") as folder:
        members = set(archive.namelist())
        if SSD not in members:
            raise ConfigError(f"{name} has no {SSD}")
        root = _xml(archive, SSD, name)
        system = root.find("ssd:System", NS)
        if root.tag != _q("ssd:SystemStructureDescription") or system is None:
            raise ConfigError(f"{name}: {SSD} is not an SSP 1.0 system structure description")
        connectors = {}
        for element in system.iterfind("ssd:Elements/ssd:Component", NS):
            component, source = element.get("name"), element.get("source") or ""
            if source not in members:
                raise ConfigError(f"{name}: component {component!r} names its FMU {source!r}, which is not in the package")
            fmu = os.path.join(folder, f"{len(package.components)}.fmu")
            with open(fmu, "wb") as file:
                file.write(archive.read(source))
            problems = check_contract(fmu, ())
            if problems:
                raise ConfigError(f"{name}: component {component!r} ({source}) cannot be used: "
                                  + "; ".join(p.replace(fmu, source) for p in problems))
            try:
                package.variables[component] = declared_variables(fmu)
            except Exception as error:  # fmpy's schema validation of the model description
                raise ConfigError(f"{name}: component {component!r} ({source}) has an unreadable model description: "
                                  f"{' '.join(str(error).split())[:300]}") from None
            package.components[component] = source
            connectors[component] = {c.get("name"): c.get("kind") for c in element.iterfind("ssd:Connectors/ssd:Connector", NS)}
            package.bindings[component] = [b.get("source") for b in element.iterfind(
                "ssd:ParameterBindings/ssd:ParameterBinding", NS) if b.get("source")]
        for connection in system.iterfind("ssd:Connections/ssd:Connection", NS):
            ends = [(connection.get(f"{end}Element"), connection.get(f"{end}Connector")) for end in ("start", "end")]
            text = " -> ".join(f"{e}.{c}" for e, c in ends)
            for (element, connector), causality in zip(ends, ("output", "input")):
                if element not in package.components:
                    raise ConfigError(f"{name}: connection {text}: no component named {element!r}")
                declared = package.variables[element].get(connector)
                if declared is None:
                    raise ConfigError(f"{name}: connection {text}: {package.components[element]} has no variable "
                                      f"{connector!r}")
                if declared[0] != causality:
                    raise ConfigError(f"{name}: connection {text}: {element}.{connector} is an {declared[0]}, not an "
                                      f"{causality}")
                if connector not in connectors[element]:
                    raise ConfigError(f"{name}: connection {text}: component {element!r} declares no connector "
                                      f"{connector!r}")
            kinds = [package.variables[e][c][1] for e, c in ends]
            if kinds[0] != kinds[1]:
                raise ConfigError(f"{name}: connection {text}: a {kinds[0]} output feeds a {kinds[1]} input")
            package.connections.append(tuple(x for end in ends for x in end))
        package.parameters = sorted(m for m in members if m.endswith(".ssv"))
        for component, sources in package.bindings.items():
            for source in sources:
                check_parameters(archive, name, source, package.variables[component], component)
        experiment = root.find("ssd:DefaultExperiment", NS)
        if experiment is not None:
            package.stop_time = _time(name, "stopTime", experiment.get("stopTime"))
            step = experiment.find(".//osp:FixedStepAlgorithm", NS)
            package.step_size = _time(name, "baseStepSize", step.get("baseStepSize") if step is not None else None)
    return package


def _time(name: str, attribute: str, text: str | None) -> float | None:
    """A default experiment's time attribute (s): None if absent, else a positive finite number."""
    if text is None or not text.strip():
        return None
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(f"{name}: its default experiment's {attribute} = {text[:40]!r} is not a positive finite "
                          "number of seconds")
    return value


def check_parameters(archive: zipfile.ZipFile, name: str, source: str, declared: dict, component: str) -> dict:
    """The parameter file ``source`` of the package, checked against the component's FMU: ``{name: (type, value)}``."""
    if source not in archive.namelist():
        raise ConfigError(f"{name}: component {component!r} binds the parameter file {source!r}, which is not in "
                          "the package")
    root = _xml(archive, source, name)
    values = {}
    for parameter in root.iterfind("ssv:Parameters/ssv:Parameter", NS):
        variable, typed = parameter.get("name"), next(iter(parameter), None)
        kind = typed.tag.rpartition("}")[2] if typed is not None else "none"
        if variable not in declared:
            raise ConfigError(f"{name}: {source} sets {variable!r}, which the {component} FMU does not have")
        if declared[variable][0] not in ("parameter", "input"):
            raise ConfigError(f"{name}: {source} sets {component}.{variable}, an {declared[variable][0]}")
        if kind != declared[variable][1]:
            raise ConfigError(f"{name}: {source} sets {component}.{variable} as a {kind}; the FMU declares a "
                              f"{declared[variable][1]}")
        try:
            values[variable] = (kind, _parse(kind, typed.get("value", "")))
        except ValueError:
            raise ConfigError(f"{name}: {source} sets {component}.{variable} to {typed.get('value')!r}, not a "
                              f"{kind}") from None
    return values


def trial_parameters(package: Package, trial: str | None) -> dict:
    """``{component: {name: (type, value)}}``: each component's bound parameters, the agent's replaced by
    the parameter file ``resources/trials/<trial>.ssv`` when ``trial`` is given."""
    name = os.path.basename(package.path)
    with zipfile.ZipFile(package.path) as archive:
        chosen = {component: (sources[0] if sources else None) for component, sources in package.bindings.items()}
        if trial is not None:
            source = f"{TRIALS}/{trial}.ssv"
            if source not in package.parameters:
                known = sorted(Path(p).stem for p in package.parameters if p.startswith(TRIALS + "/"))
                raise ConfigError(f"{name} has no trial {trial!r} (have: {', '.join(known) or 'none'})")
            chosen[AGENT] = source
        return {component: check_parameters(archive, name, source, package.variables[component], component)
                if source else {} for component, source in chosen.items()}


def run_ssp(path, master: str, trial: str | None = None, steps: int | None = None, timeout: float | None = None) -> dict:
    """Run an SSP package, unchanged, under an FMI master of someone else's, in a child process.

    Parameters
    ----------
    path : path
        The .ssp file (checked first: :func:`read_ssp`).
    master : str
        ``fmpy`` (FMPy's SSP master, ``fmpy.ssp.simulation.simulate_ssp``) or ``libcosim``
        (``CosimExecution.from_ssp_file``).
    trial : str, optional
        A parameter file of ``resources/trials`` (``conv_left_sync_0``) for the agent, in place of the one
        the SSD binds; the same values are given to both masters as their API takes them.
    steps : int, optional
        Communication steps (default: the default experiment's stop time over its step size).
    timeout : float, optional
        Seconds for the child process.

    Returns
    -------
    dict
        ``"time"`` (steps,) s, the end of each step; ``"component.variable"`` (steps,) after each step,
        for every Real input and output of the components (FMPy: every connector of the SSD).

    Raises
    ------
    ConfigError
        A bad package, master, trial or step count.
    SimulationError
        The master failed (its one-line reason).
    """
    import importlib.util

    if master not in MASTERS:
        raise ConfigError(f"--master {master!r} is not one of {', '.join(MASTERS)}")
    if master == "libcosim" and importlib.util.find_spec("libcosimpy") is None:
        raise ConfigError("--master libcosim needs libcosimpy (pip install libcosimpy==0.0.6, in the test extra)")
    package = read_ssp(path)
    parameters = trial_parameters(package, trial)
    if package.step_size is None:
        raise ConfigError(f"{os.path.basename(package.path)}: its default experiment gives no step size")
    if steps is None:
        if package.stop_time is None:
            raise ConfigError(f"{os.path.basename(package.path)}: its default experiment gives no stop time")
        steps = round(package.stop_time / package.step_size)
    if steps < 1:
        raise ConfigError(f"steps must be at least 1, got {steps}")
    if steps > MAX_STEPS:
        raise ConfigError(f"{os.path.basename(package.path)}: {steps} steps, over the limit of {MAX_STEPS} "
                          "(lower the stop time, or give --steps)")
    with tempfile.TemporaryDirectory(prefix="rhi_ssp_run_") as folder:
        unpacked, fmus = unpack(package, Path(folder))
        request = Path(folder) / "request.json"
        request.write_text(json.dumps({
            "ssp": str(unpacked), "fmus": fmus, "master": master, "steps": steps, "step_size": package.step_size,
            "parameters": {c: {k: [t, v] for k, (t, v) in values.items()} for c, values in parameters.items()},
            "connectors": {c: [v for v, (causality, kind) in package.variables[c].items()
                               if causality in ("input", "output") and kind == "Real"] for c in package.components},
            "out": str(Path(folder) / "result.npz")}))
        scratch = Path(folder) / "tmp"  # the masters' own unpacked copies, removed with the folder
        scratch.mkdir()
        env = {**os.environ, "TMPDIR": str(scratch),
               "PYTHONPATH": os.pathsep.join(filter(None, [str(Path(__file__).resolve().parents[2]),
                                                           os.environ.get("PYTHONPATH")]))}
        try:
            done = subprocess.run([sys.executable, "-m", "master.export.ssp_runner", str(request)], capture_output=True,
                                  text=True, timeout=timeout, env=env)
        except subprocess.TimeoutExpired:
            raise SimulationError(master, 0.0, f"did not finish within {timeout:g} s", "error") from None
        if done.returncode != 0 or not (Path(folder) / "result.npz").is_file():
            lines = [line for line in done.stderr.splitlines() if line.strip()]
            reason = lines[-1] if lines else f"the child process ended with status {done.returncode}"
            raise SimulationError(master, 0.0, reason.removeprefix("rhi-ssp-runner: "), "error")
        with np.load(Path(folder) / "result.npz") as result:
            return {key: result[key] for key in result.files}


def unpack(package: Package, folder: Path) -> tuple[Path, dict]:
    """The checked package unpacked for a master: ``folder/ssp`` holds it (every member checked,
    :func:`components.archives.extract`), each component's FMU unpacked (checked) into ``folder/fmus/N``
    and, at its place in the package, packed again from those checked files (libcosim takes an FMU only
    as a zip archive, and unpacks it itself). Returns the package's folder and ``{source: FMU folder}``."""
    from components.archives import ArchiveError, extract, pack

    ssp, fmus = folder / "ssp", {}
    try:
        extract(package.path, ssp)
        for index, source in enumerate(package.components.values()):
            fmus[source] = str(extract(ssp / source, folder / "fmus" / str(index)))
            (ssp / source).unlink()
            pack(fmus[source], ssp / source)
    except ArchiveError as error:
        raise ConfigError(str(error)) from None
    return ssp, fmus


def final_drift_cm(values: dict, agent: str = AGENT, body: str = BODY) -> float:
    """The drift after the last step (cm): x of the forward kinematics of the agent's mu minus x of the body's
    sensed angles, as ``master.experiment.measures`` computes it."""
    perceived, _ = kinematics.forward(values[f"{agent}.mu_shoulder"][-1], values[f"{agent}.mu_elbow"][-1])
    real, _ = kinematics.forward(values[f"{body}.q_shoulder"][-1], values[f"{body}.q_elbow"][-1])
    return float(100.0 * (perceived - real))


def parse_trial(text: str, config: dict, kind: str) -> Trial:
    """``left/sync/0`` -> the protocol's trial of decoder ``kind`` (ConfigError naming what is unknown)."""
    from master.experiment.protocol import make_trial

    parts = text.split("/")
    if len(parts) != 3 or not parts[2].isdigit():
        raise ConfigError(f"--trial {text!r} must be CONDITION/STIMULATION/INDEX, e.g. left/sync/0")
    condition, stimulation, index = parts[0], parts[1], int(parts[2])
    for table, value in (("conditions", condition), ("stimulations", stimulation)):
        if value not in config[table]:
            raise ConfigError(f"--trial {text!r}: no {table[:-1]} {value!r} (have: {', '.join(config[table])})")
    return make_trial(config, kind, condition, stimulation, index)


def export_system(out, config: dict, kind: str | None = None, variant: str = "native", body: str | None = None,
                  trial: str | None = None) -> Path:
    """``rhi export-system``: the agent FMU, a body FMU (``variant`` exported, or the user's ``body``, checked
    against the body contract) and the SSP package around them, at ``out``; everything checked first.

    Parameters
    ----------
    out : path
        The .ssp to write.
    config : dict
        A loaded configuration (protocol, step size, steps, parameters, decoder).
    kind : str, optional
        The decoder (default: the configuration's first).
    variant : str
        The body exported with ``rhi export-body`` (native, kinematic, kinematic-c), when ``body`` is None.
    body : str, optional
        A body FMU of one's own.
    trial : str, optional
        ``CONDITION/STIMULATION/INDEX``: the trial the SSD binds (default: the protocol's first).

    Returns
    -------
    Path
        ``out``.
    """
    from components.body.contract import BODY_CONTRACT
    from components.fmu import check_contract
    from master.export.agent_fmu import export_agent
    from master.export.body import VARIANT_NAMES, export_body

    out = check_output_file(out, "SSP file", ".ssp")
    kind = kind or config["experiment"]["decoders"][0]
    bound = parse_trial(trial, config, kind) if trial else None
    if body is not None:
        problems = check_contract(body, BODY_CONTRACT)
        if problems:
            raise ConfigError(f"--body {body} cannot be used ({len(problems)} problem{'s' * (len(problems) > 1)}): "
                              + "; ".join(problems))
    elif variant not in VARIANT_NAMES:
        raise ConfigError(f"--body-variant {variant!r} is not one of {', '.join(VARIANT_NAMES)}")
    with tempfile.TemporaryDirectory(prefix="rhi_system_") as folder:
        agent, _ = export_agent(Path(folder) / "Agent.fmu", config, kind)
        body = body or str(export_body(Path(folder) / "Body.fmu", variant))
        return build_ssp(out, str(agent), body, config, kind, bound)


def write_csv(out, values: dict) -> Path:
    """The run's values as CSV (``time`` first, one row per step), written whole or not at all."""
    import csv
    import io

    names = ["time"] + sorted(k for k in values if k != "time")
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(names)
    for row in zip(*(values[name] for name in names)):
        writer.writerow([repr(float(v)) for v in row])
    atomic_write(out, text.getvalue())
    return Path(out)
