"""An SSP 1.0 package of the experiment or the reach: its layout, its parameter sets, and :func:`build_ssp`.

The package::

    SystemStructure.ssd            the system: components agent and body, their connectors and connections
                                   (the task's links between body and brain), the step size and stop time
    resources/agent.fmu            the agent FMU (agent_fmu.py)
    resources/body.fmu             the body FMU (body.py / c_body.py, or the user's)
    resources/body.ssv             the body's parameters (the task's [body] keys it declares)
    resources/trials/<decoder>_<condition>_<stimulation>_<index>.ssv
                                   the agent's parameters for each trial of the protocol, its seed included
                                   (the reach: <decoder>_<band>_<index>.ssv, each goal of the reach plan)

One parameter file per trial, not per condition: each trial has its own seed (protocol.trial_seed),
so a set per condition could not reproduce the experiment's trials; and libcosim applies only the
first parameter set bound to each component, so the SSD binds exactly one trial (the first of the
protocol, or the one asked for) and the others lie beside it for a tool to bind instead.
"""
from __future__ import annotations

import math
import re
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np

from rhi.master.cosim import ConfigError
from rhi.master.config.sources import shared_parameters
from rhi.master.export.agent import agent_connections
from rhi.master.tasks import exportable as task_named
from rhi.master.outputs.files import atomic_write
from rhi.master.outputs.out_file import check_output_file, place_file

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
MASTERS = ("fmpy", "libcosim", "ecos")
# run-system's communication steps: 2.8 h of the experiment's 0.01 s steps, its recorded connectors (about 20
# float64 each) 160 MB; far beyond the protocol's runs, far below what would exhaust memory or run for days.
MAX_STEPS = 1_000_000

for _prefix, _uri in NS.items():
    ET.register_namespace(_prefix, _uri)


def qualified(tag: str) -> str:
    """``"ssd:System"`` as ElementTree names it: ``"{namespace}System"``, the prefix's namespace from ``NS``."""
    prefix, _, name = tag.partition(":")
    return f"{{{NS[prefix]}}}{name}"


def format_value(kind: str, value) -> str:
    """``value`` (a scalar or a one-element array) as an SSV value of FMI type ``kind``: ``true`` or ``false``, an
    integer, or a real (``repr``; ``INF``, ``-INF``, ``NaN``)."""
    if kind == "Boolean":
        return "true" if bool(np.asarray(value).item()) else "false"
    if kind == "Integer":
        return str(int(np.asarray(value).item()))
    value = float(np.asarray(value).item())
    return {float("inf"): "INF", float("-inf"): "-INF"}.get(value, "NaN" if value != value else repr(value))


INTEGER_RANGE = (-2 ** 31, 2 ** 31 - 1)  # an FMI 2.0 Integer is a C int
_INTEGER = re.compile(r"[+-]?[0-9]+")
_REAL = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?")


def parse_value(kind: str, text: str):
    """An SSV value ``text`` of FMI type ``kind``: a bool (``true``, ``false``, ``1``, ``0``), an int within a C
    int's range, or a finite float (libcosim reads none of ``NaN``, ``INF``, and C++ streams refuse
    ``1e400``).

    Raises
    ------
    ValueError
        Why ``text`` is not such a value, in words (``not finite``, ``outside [...]``).
    """
    text = text.strip()
    if kind == "Boolean":
        if text not in ("true", "false", "1", "0"):
            raise ValueError("not a Boolean (true, false, 1 or 0)")
        return text in ("true", "1")
    if kind == "Integer":
        if not _INTEGER.fullmatch(text) or not INTEGER_RANGE[0] <= int(text) <= INTEGER_RANGE[1]:
            raise ValueError(f"not an Integer within [{INTEGER_RANGE[0]}, {INTEGER_RANGE[1]}]")
        return int(text)
    if kind != "Real" or not _REAL.fullmatch(text) or not math.isfinite(float(text)):
        raise ValueError(f"not a finite {kind}" if kind == "Real" else f"not a {kind}")
    return float(text)


def parameter_set(name: str, values: dict[str, tuple[str, object]], starts: dict | None = None) -> bytes:
    """An SSV file: ``values`` is ``{parameter: (FMI type, value)}``, names relative to the component.

    A value that is not finite (``brain.spatial_sd = inf``, the paper's model) is left out: libcosim reads
    numbers with C++ streams, which do not take XML Schema's ``INF``, and refuses the whole package. It
    must then equal the FMU's own start value (``starts``: ``{parameter: start}``), which the FMU keeps.
    """
    root = ET.Element(qualified("ssv:ParameterSet"), {"version": "1.0", "name": name})
    parameters = ET.SubElement(root, qualified("ssv:Parameters"))
    for parameter, (kind, value) in values.items():
        if kind == "Real" and not np.isfinite(float(np.asarray(value).item())):
            start = (starts or {}).get(parameter)
            if start is None or float(start) != float(np.asarray(value).item()):
                raise ConfigError(f"{name}: {parameter} = {float(np.asarray(value).item())} cannot be written for "
                                  f"libcosim and differs from the FMU's start value {start}")
            continue
        element = ET.SubElement(parameters, qualified("ssv:Parameter"), {"name": parameter})
        ET.SubElement(element, qualified(f"ssv:{kind}"), {"value": format_value(kind, value)})
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8") + b"\n"


def body_parameters(config: dict, declared: dict) -> dict:
    """The body FMU's parameters: the configuration's ``body.*`` values that the body declares (as run_batch);
    the same for every trial."""
    return {path.partition(".")[2]: (declared[path.partition(".")[2]][1], np.asarray(value).reshape(-1)[0])
            for path, value in shared_parameters(config, (BODY,)).items()
            if path.partition(".")[2] in declared}


def declared_variables(fmu: str) -> dict[str, tuple[str, str]]:
    """``{name: (causality, FMI type)}`` of an FMU's scalar variables."""
    from fmpy import read_model_description
    return {v.name: (v.causality, v.type) for v in read_model_description(fmu, validate=False).modelVariables}


def declared_ranges(fmu: str) -> dict[str, tuple[float | None, float | None]]:
    """``{name: (min, max)}`` of an FMU's Real and Integer variables (None where it declares no bound)."""
    from fmpy import read_model_description

    def bound(text):
        return None if text is None else float(text)
    return {v.name: (bound(v.min), bound(v.max)) for v in read_model_description(fmu, validate=False).modelVariables
            if v.type in ("Real", "Integer")}


def start_values(fmu: str) -> dict[str, float]:
    """``{name: start}`` of an FMU's Real variables that have a start value."""
    from fmpy import read_model_description
    return {v.name: float(v.start) for v in read_model_description(fmu, validate=False).modelVariables
            if v.type == "Real" and v.start is not None}


def system_description(agent: dict, body: dict, bound: str, step_size: float, stop_time: float, name: str,
                       description: str = "the rubber-hand agent and a body", links=None) -> bytes:
    """SystemStructure.ssd: the agent and body components (every input and output a connector), their
    connections (:func:`~rhi.master.export.agent.agent_connections` of the body's ``links``, default the
    experiment's), the bound parameter files and the default experiment (libcosim's fixed-step algorithm
    annotation carries the step size)."""
    root = ET.Element(qualified("ssd:SystemStructureDescription"), {"version": "1.0", "name": name, "generationTool": "rhi"})
    system = ET.SubElement(root, qualified("ssd:System"), {"name": name, "description": description})
    elements = ET.SubElement(system, qualified("ssd:Elements"))
    for component, declared, parameters in ((AGENT, agent, f"{TRIALS}/{bound}.ssv"), (BODY, body, BODY_PARAMETERS)):
        element = ET.SubElement(elements, qualified("ssd:Component"),
                                {"name": component, "type": FMU_TYPE, "source": SOURCES[component]})
        connectors = ET.SubElement(element, qualified("ssd:Connectors"))
        for variable, (causality, kind) in declared.items():
            if causality in ("input", "output"):
                connector = ET.SubElement(connectors, qualified("ssd:Connector"), {"name": variable, "kind": causality})
                ET.SubElement(connector, qualified(f"ssc:{kind}"))
        bindings = ET.SubElement(element, qualified("ssd:ParameterBindings"))
        ET.SubElement(bindings, qualified("ssd:ParameterBinding"), {"type": "application/x-ssp-parameter-set",
                                                             "source": parameters})
    connections = ET.SubElement(system, qualified("ssd:Connections"))
    for source, target in agent_connections(AGENT, BODY, links):
        (start, start_connector), (end, end_connector) = source.split("."), target.split(".")
        ET.SubElement(connections, qualified("ssd:Connection"), {"startElement": start, "startConnector": start_connector,
                                                         "endElement": end, "endConnector": end_connector})
    experiment = ET.SubElement(root, qualified("ssd:DefaultExperiment"), {"startTime": "0.0", "stopTime": repr(stop_time)})
    annotation = ET.SubElement(ET.SubElement(experiment, qualified("ssd:Annotations")), qualified("ssc:Annotation"),
                               {"type": "com.opensimulationplatform"})
    ET.SubElement(ET.SubElement(annotation, qualified("osp:Algorithm")), qualified("osp:FixedStepAlgorithm"),
                  {"baseStepSize": repr(step_size)})
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8") + b"\n"


def build_ssp(out, agent_fmu: str, body_fmu: str, config: dict, kind: str, bound=None, task: str = "illusion") -> Path:
    """Write the SSP package at ``out`` (a path ending in .ssp), whole or not at all.

    Parameters
    ----------
    out : path
        The package to write.
    agent_fmu, body_fmu : str
        The FMUs (agent_fmu.build_agent_fmu of ``task``; a body meeting the body contract).
    config : dict
        The task's configuration: the protocol or the reach plan (one parameter file per trial or goal of
        decoder ``kind``), the step size and number of steps, the body's keys.
    kind : str
        The decoder the agent FMU carries.
    bound : Trial or ReachTrial, optional
        The trial the SSD binds (default: the task's first of ``kind``).
    task : str
        ``illusion`` or ``reach`` (:func:`rhi.master.tasks.exportable`).

    Returns
    -------
    Path
        ``out``.
    """
    out = check_output_file(out, "SSP file", ".ssp")
    task = task_named(task)
    trials = task.trials(config, kind)
    bound = bound or trials[0]
    if bound not in trials:
        trials.append(bound)
    agent, body, agent_starts = declared_variables(agent_fmu), declared_variables(body_fmu), start_values(agent_fmu)
    experiment = config["experiment"]
    ssd = system_description(agent, body, task.trial_name(bound), experiment["step_size"],
                             experiment["steps"] * experiment["step_size"], task.system_name, task.system_description,
                             task.links(config))

    def write(file):
        with zipfile.ZipFile(file, "w", zipfile.ZIP_DEFLATED) as archive:
            archive.writestr(SSD, ssd)
            archive.write(agent_fmu, SOURCES[AGENT])
            archive.write(body_fmu, SOURCES[BODY])
            archive.writestr(BODY_PARAMETERS, parameter_set("body", body_parameters(config, body),
                                                            start_values(body_fmu)))
            for trial in trials:
                name = task.trial_name(trial)
                archive.writestr(f"{TRIALS}/{name}.ssv", parameter_set(
                    name, task.agent_values(trial, config, agent, agent_starts), agent_starts))

    atomic_write(out, write, place_file)  # never over a file that appeared at out meanwhile
    return out
