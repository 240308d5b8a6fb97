"""Checking an FMU file against a contract before anything loads it: the archive, the FMI version, the
co-simulation interface and its binary for this platform, and each contract port's causality, type, unit and
value reference."""
from __future__ import annotations

import os
import zipfile
from xml.etree import ElementTree as ET

from ..archives import ArchiveError, check_archive

SCALAR_TYPES = ("Real", "Integer", "Boolean")
CAUSALITY = {"parameter": "parameter", "input": "input", "output": "output",
             "local": "local", "calculatedParameter": "local"}  # 'independent' (time) is not a port


def library_path(unzipdir: str, model_identifier: str) -> str:
    """The path of an FMU's shared library for this platform.

    Parameters
    ----------
    unzipdir : str
        The unzipped FMU's folder (``""``: the path inside the FMU).
    model_identifier : str
        The co-simulation ``modelIdentifier``: the library's name.

    Returns
    -------
    str
        ``unzipdir/binaries/<platform>/<model_identifier><extension>``, fmpy's platform and extension.
    """
    import fmpy
    return os.path.join(unzipdir, "binaries", fmpy.platform, model_identifier + fmpy.sharedLibraryExtension)


def check_contract(path, contract=()) -> list[str]:
    """Every reason the file at ``path`` cannot serve as an FMU honouring ``contract`` (empty: fine)."""
    path = os.fspath(path)
    if os.path.isdir(path):
        return [f"{path} is a folder, not an FMU file"]
    if os.path.exists(path) and not os.path.isfile(path):
        return [f"{path} is not a regular file"]
    if not os.path.isfile(path):
        return [f"{path} does not exist"]
    if not zipfile.is_zipfile(path):
        return [f"{path} is not an FMU: it is not a zip archive"]
    try:
        check_archive(path)
    except ArchiveError as error:
        return [str(error)]
    with zipfile.ZipFile(path) as archive:
        names = set(archive.namelist())
        if "modelDescription.xml" not in names:
            return [f"{path} has no modelDescription.xml"]
        try:
            root = ET.fromstring(archive.read("modelDescription.xml"))
        except ET.ParseError as error:
            return [f"{path}: modelDescription.xml is not valid XML ({error})"]
    if str(root.get("fmiVersion")).startswith("3") and root.find("ModelVariables/ScalarVariable") is None:
        # an FMI 3.0 description has no 2.0 port to compare: the version is the one problem worth naming
        return [f"FMI version {root.get('fmiVersion')!r}, need 2.0 (export the body with --fmi 2.0)"]
    problems = []
    if root.get("fmiVersion") != "2.0":
        problems.append(f"FMI version {root.get('fmiVersion')!r}, need 2.0")
    co_simulation, model_exchange = root.find("CoSimulation"), root.find("ModelExchange")
    if co_simulation is None:
        problems.append("model exchange only: no CoSimulation interface" if model_exchange is not None
                        else "no CoSimulation interface")
    interface = co_simulation if co_simulation is not None else model_exchange
    if interface is not None:
        binary = library_path("", interface.get("modelIdentifier", "")).replace(os.sep, "/")
        if binary not in names:
            problems.append(f"no binary for this platform ({binary} is missing)")
    declared, references = {}, {}
    for element in root.iterfind("ModelVariables/ScalarVariable"):
        typed = next(iter(element), None)
        declared[element.get("name")] = (element.get("causality", "local"),
                                         typed.tag if typed is not None else "none", _unit(root, typed))
        references[element.get("name")] = element.get("valueReference")
    problems += _shared_references(contract, declared, references)
    for wanted in contract:
        if wanted.name not in declared:
            problems.append(f"missing variable {wanted.name} ({wanted.causality} {wanted.type}"
                            f"{' in ' + wanted.unit if wanted.unit else ''})")
            continue
        causality, kind, unit = declared[wanted.name]
        if causality != wanted.causality:
            problems.append(f"{wanted.name} has causality {causality}, the contract needs {wanted.causality}")
        if kind != wanted.type:
            problems.append(f"{wanted.name} has type {kind}, the contract needs {wanted.type}")
        elif unit != wanted.unit:
            problems.append(f"{wanted.name} has unit {unit or 'none'!r}, the contract needs {wanted.unit or 'none'!r}")
    return problems


def _shared_references(contract, declared, references) -> list[str]:
    """Each contract port whose value reference an earlier port of the same type already has: an FMU
    reads and writes by reference, so the two would be one value (an alias), not two ports."""
    owner, problems = {}, []
    for wanted in contract:
        if wanted.name not in declared or references.get(wanted.name) is None:
            continue
        key = (declared[wanted.name][1], references[wanted.name])
        if key in owner:
            problems.append(f"{wanted.name} has the value reference {key[1]} of {owner[key]}: the two ports would "
                            "be one value")
        else:
            owner[key] = wanted.name
    return problems


def _unit(root, typed) -> str:
    """The unit of a typed element, its own or its declared type's."""
    if typed is None:
        return ""
    if typed.get("unit") is not None or typed.get("declaredType") is None:
        return typed.get("unit", "")
    for simple in root.iterfind("TypeDefinitions/SimpleType"):
        if simple.get("name") == typed.get("declaredType") and len(simple):
            return simple[0].get("unit", "")
    return ""
