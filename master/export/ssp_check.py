"""Reading an SSP package and checking it before it runs (:func:`read_ssp`): one ConfigError naming the first
problem (not a zip, no SystemStructure.ssd, an FMU missing from the package or unusable, a connection or a
parameter naming a variable its FMU lacks or of the wrong causality or type)."""
from __future__ import annotations

import math
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from xml.etree import ElementTree as ET

from rhi.master.cosim import ConfigError
from rhi.master.export.ssp_package import (AGENT, NS, SSD, TRIALS, declared_ranges, declared_variables, parse_value,
                                       qualified)
from rhi.master.outputs.scratch import scratch_folder


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
    ranges : dict
        ``name -> {variable: (min, max)}``: each Real and Integer variable's declared bounds (None: unbounded).
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
    ranges: dict = field(default_factory=dict)
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
        variable that does not exist or of the wrong causality or type, a parameter its FMU lacks, a
        parameter value not of its type (not finite, an Integer beyond a C int, a Boolean not true or
        false) or outside the range its FMU declares.
    """
    from rhi.components.archives import ArchiveError, check_archive
    from rhi.components.fmu import check_contract

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
    with zipfile.ZipFile(path) as archive, scratch_folder("rhi_ssp_check_") as folder:
        members = set(archive.namelist())
        if SSD not in members:
            raise ConfigError(f"{name} has no {SSD}")
        root = _xml(archive, SSD, name)
        system = root.find("ssd:System", NS)
        if root.tag != qualified("ssd:SystemStructureDescription") or system is None:
            raise ConfigError(f"{name}: {SSD} is not an SSP 1.0 system structure description")
        connectors = {}
        for element in system.iterfind("ssd:Elements/ssd:Component", NS):
            component, source = element.get("name"), element.get("source") or ""
            if component in package.components:  # a master would make two instances, or one: never what was meant
                raise ConfigError(f"{name}: component {component!r} is declared twice in {SSD}; each component's "
                                  "name must be its own")
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
                package.ranges[component] = declared_ranges(fmu)
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
                check_parameters(archive, name, source, package.variables[component], component,
                                 package.ranges[component])
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


def check_parameters(archive: zipfile.ZipFile, name: str, source: str, declared: dict, component: str,
                     ranges: dict | None = None) -> dict:
    """The parameter file ``source`` of the package, checked against the component's FMU (``declared``, its
    variables' causality and type; ``ranges``, their declared bounds): ``{name: (type, value)}``."""
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
        text = typed.get("value", "")
        try:
            values[variable] = (kind, parse_value(kind, text))
        except ValueError as error:
            raise ConfigError(f"{name}: {source} sets {component}.{variable} to {text[:40]!r}, {error}") from None
        low, high = (ranges or {}).get(variable, (None, None))
        value = values[variable][1]
        if low is not None and value < low or high is not None and value > high:
            raise ConfigError(f"{name}: {source} sets {component}.{variable} = {value:g}, outside the range "
                              f"[{'-inf' if low is None else f'{low:g}'}, {'inf' if high is None else f'{high:g}'}] "
                              "its FMU declares")
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
        return {component: check_parameters(archive, name, source, package.variables[component], component,
                                            package.ranges[component])
                if source else {} for component, source in chosen.items()}
