"""Any FMI 2.0 co-simulation FMU as a native component, on top of fmpy.

:class:`FMUComponent` reads the FMU's model description and declares one
:class:`~components.variables.Variable` per scalar Real, Integer or Boolean
variable (causality, unit, start, range, description and the output
dependencies of ``ModelStructure``), so the master validates and wires an FMU
exactly like a component written in Python. A batch of B trials is B FMU
instances; ``do_step`` steps each of them.

Before anything runs, :func:`check_contract` checks the file against a
contract (by default :data:`BODY_CONTRACT`, DESIGN.md "Body FMU contract") and
the constructor raises one ComponentError that lists every problem found.

Example::

    body = FMUComponent("Body.fmu")           # name "body", checked against BODY_CONTRACT
    system = System([..., brain, body], [("brain.u_shoulder", "body.u_shoulder"), ...])
"""
from __future__ import annotations

import atexit
import collections
import ctypes
import os
import shutil
import sys
import zipfile
from dataclasses import dataclass
from xml.etree import ElementTree as ET

import numpy as np

from components.component import INITIALIZATION, STEPPING, Component, ComponentError, Status, StepFailure
from components.variables import Variable


@dataclass(frozen=True)
class ContractVariable:
    """A variable an FMU must have: name, causality, FMI type and unit ('' for none)."""

    name: str
    causality: str
    type: str
    unit: str = ""


BODY_CONTRACT = (
    ContractVariable("u_shoulder", "input", "Real", "deg/s"),
    ContractVariable("u_elbow", "input", "Real", "deg/s"),
    ContractVariable("q_shoulder", "output", "Real", "deg"),
    ContractVariable("q_elbow", "output", "Real", "deg"),
    ContractVariable("hand_x", "output", "Real", "m"),
    ContractVariable("hand_y", "output", "Real", "m"),
    ContractVariable("force_x", "output", "Real", "N"),
    ContractVariable("force_y", "output", "Real", "N"),
    ContractVariable("held", "parameter", "Boolean"),
    ContractVariable("q0_shoulder", "parameter", "Real", "deg"),
    ContractVariable("q0_elbow", "parameter", "Real", "deg"),
)

SCALAR_TYPES = ("Real", "Integer", "Boolean")
CAUSALITY = {"parameter": "parameter", "input": "input", "output": "output",
             "local": "local", "calculatedParameter": "local"}  # 'independent' (time) is not a port


def library_path(unzipdir: str, model_identifier: str) -> str:
    import fmpy
    return os.path.join(unzipdir, "binaries", fmpy.platform, model_identifier + fmpy.sharedLibraryExtension)


def check_contract(path, contract=BODY_CONTRACT) -> list[str]:
    """Every reason the file at ``path`` cannot serve as an FMU honouring ``contract`` (empty: fine)."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        return [f"{path} does not exist"]
    if not zipfile.is_zipfile(path):
        return [f"{path} is not an FMU: it is not a zip archive"]
    with zipfile.ZipFile(path) as archive:
        names = set(archive.namelist())
        if "modelDescription.xml" not in names:
            return [f"{path} has no modelDescription.xml"]
        try:
            root = ET.fromstring(archive.read("modelDescription.xml"))
        except ET.ParseError as error:
            return [f"{path}: modelDescription.xml is not valid XML ({error})"]
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
    declared = {}
    for element in root.iterfind("ModelVariables/ScalarVariable"):
        typed = next(iter(element), None)
        declared[element.get("name")] = (element.get("causality", "local"),
                                         typed.tag if typed is not None else "none", _unit(root, typed))
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


# pythonfmu's export library (0.7) holds a global shared_ptr that C++ destroys at process exit and
# then resets again from its __attribute__((destructor)): a use-after-free that randomly aborts the
# process at exit ("corrupted double-linked list"). Calling the exported finalizePythonInterpreter
# from atexit, while the pointer is still alive, empties it, so both exit-time releases do nothing.
# We hold a handle on each such library (it cannot unload under us) and unzip each FMU once.
_GUARDED: dict[str, ctypes.CDLL] = {}
_EXTRACTED: dict[tuple, str] = {}


def guard_library(unzipdir: str, model_identifier: str) -> None:
    """Hold the FMU's shared library loaded and, if it is pythonfmu's, release its state at exit."""
    path = library_path(unzipdir, model_identifier)
    if path not in _GUARDED:
        library = ctypes.CDLL(path)
        _GUARDED[path] = library if hasattr(library, "finalizePythonInterpreter") else None


def extracted(path: str) -> str:
    """The FMU at ``path`` unzipped, once per process and file version (removed at exit)."""
    from fmpy import extract
    status = os.stat(path)
    key = (path, status.st_mtime_ns, status.st_size)
    if key not in _EXTRACTED:
        _EXTRACTED[key] = extract(path)
    return _EXTRACTED[key]


@atexit.register
def _release() -> None:
    for library in filter(None, _GUARDED.values()):
        library.finalizePythonInterpreter()
    for folder in _EXTRACTED.values():
        shutil.rmtree(folder, ignore_errors=True)


def _parse(kind: str, text):
    if text is None:
        return None
    if kind == "Boolean":
        return text in ("true", "1")
    return int(text) if kind == "Integer" else float(text)


class FMUComponent(Component):
    """An FMI 2.0 co-simulation FMU behaving as a native component.

    path: the .fmu file. name: instance name in the system.
    contract: variables the FMU must have (None: check only that it is a usable FMU).
    """

    def __init__(self, path, name: str = "body", contract=BODY_CONTRACT):
        from fmpy import read_model_description
        self.path = os.path.abspath(os.fspath(path))
        problems = check_contract(self.path, contract or ())
        if problems:
            raise ComponentError(f"{name}: {os.path.basename(self.path)} cannot be used ({len(problems)} "
                                 f"problem{'s' * (len(problems) > 1)}): " + "; ".join(problems))
        try:
            self.description = read_model_description(self.path)
        except Exception as error:  # fmpy's schema validation, for a file the contract check let through
            problems = getattr(error, "problems", None) or [str(error)]
            raise ComponentError(f"{name}: {os.path.basename(self.path)} cannot be used: "
                                 + "; ".join(problems)) from None
        self.label = f"FMU {self.description.modelName!r} ({os.path.basename(self.path)})"
        super().__init__(name, self._declare())
        self.instances, self.messages, self.failure = [], collections.deque(maxlen=20), None

    def _declare(self) -> list[Variable]:
        """Component variables from the model description (scalar Real, Integer, Boolean only)."""
        self.references = {}  # name -> value reference
        depends = {u.variable.name: None if u.dependencies is None else
                   tuple(v.name for v in u.dependencies if v.causality == "input")
                   for u in self.description.outputs}
        variables = []
        for v in self.description.modelVariables:
            if v.type not in SCALAR_TYPES or v.causality not in CAUSALITY:
                continue  # strings, enumerations and the independent variable have no port here
            causality = CAUSALITY[v.causality]
            unit = v.unit or (v.declaredType.unit if v.declaredType is not None else None) or ""
            bounds = {b: float(getattr(v, b)) for b in ("min", "max")
                      if getattr(v, b) is not None and v.type != "Boolean"}
            variables.append(Variable(v.name, causality, v.type, start=_parse(v.type, v.start), unit=unit,
                                      description=v.description or "", **bounds,
                                      depends_on=depends.get(v.name) if causality == "output" else None))
            self.references[v.name] = v.valueReference
        return variables

    # -- lifecycle ------------------------------------------------------------------------
    def instantiate(self, batch_size: int = 1) -> None:
        from fmpy.fmi1 import calloc, free
        from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
        super().instantiate(batch_size)
        unzipdir, identifier = extracted(self.path), self.description.coSimulation.modelIdentifier
        guard_library(unzipdir, identifier)
        self._callbacks = fmi2CallbackFunctions()  # one logger for all: FMU messages explain failures
        self._callbacks.logger = fmi2CallbackLoggerTYPE(
            lambda env, instance, status, category, message: self.messages.append(
                (message or b"").decode("utf-8", "replace").strip()))
        self._callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self._callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        saved_path = list(sys.path)  # a pythonfmu FMU prepends its resources to sys.path for good
        try:
            for trial in range(self.batch_size):
                fmu = FMU2Slave(guid=self.description.guid, unzipDirectory=unzipdir,
                                modelIdentifier=identifier, instanceName=f"{self.name}[{trial}]")
                fmu.instantiate(callbacks=self._callbacks, loggingOn=True)
                self.instances.append(fmu)
        except Exception as error:
            raise ComponentError(f"{self.name}: {self.label} could not be instantiated: {error}"
                                 f"{self._reason()}") from None
        finally:
            sys.path[:] = saved_path
        self._plan()

    def _plan(self) -> None:
        """Value-reference arrays and ctypes buffers per role and type, built once (the fast path)."""
        from fmpy.fmi2 import fmi2Boolean, fmi2Integer, fmi2Real, fmi2ValueReference
        ctype = {"Real": fmi2Real, "Integer": fmi2Integer, "Boolean": fmi2Boolean}
        self.plan = {}
        for role in ("parameter", "input", "output", "local"):
            for kind in SCALAR_TYPES:
                names = [v.name for v in self.variables.values() if v.causality == role and v.type == kind]
                if names:
                    refs = (fmi2ValueReference * len(names))(*(self.references[n] for n in names))
                    self.plan[role, kind] = (names, refs, (ctype[kind] * len(names))())

    def _set(self, *roles: str) -> None:
        for (role, kind), (names, refs, buffer) in self.plan.items():
            if role in roles:
                for fmu, row in zip(self.instances, np.stack([self.values[n] for n in names], 1).tolist()):
                    buffer[:] = row
                    getattr(fmu, f"fmi2Set{kind}")(fmu.component, refs, len(names), buffer)

    def _get(self, t: float) -> None:
        """Read outputs and locals of every instance into fresh (B,) arrays; NaN/inf fails the step."""
        for (role, kind), (names, refs, buffer) in self.plan.items():
            if role not in ("output", "local"):
                continue
            rows = np.empty((self.batch_size, len(names)), dtype=self.variables[names[0]].dtype)
            for trial, fmu in enumerate(self.instances):
                getattr(fmu, f"fmi2Get{kind}")(fmu.component, refs, len(names), buffer)
                rows[trial] = buffer[:]
            if kind == "Real" and not np.isfinite(rows).all():
                bad = np.argwhere(~np.isfinite(rows))
                trial, column = bad[0]
                raise StepFailure(f"{self.label}: output {names[column]} is {rows[trial, column]} "
                                  f"in trial {trial} at t = {t:.6g} s", trials=np.unique(bad[:, 0]))
            for column, name in enumerate(names):
                self.values[name] = rows[:, column].copy()

    def _reason(self) -> str:
        reason = " | ".join(self.messages)
        self.messages.clear()
        return f" ({reason})" if reason else ""

    def _each(self, what: str, t: float, action) -> None:
        """Run ``action(fmu)`` on every instance; a status worse than warning becomes a StepFailure."""
        from fmpy.fmi1 import FMICallException
        for trial, fmu in enumerate(self.instances):
            try:
                action(fmu)
            except FMICallException as error:
                self.failure = StepFailure(f"{self.label}: {what} returned {Status(error.status).name.lower()} "
                                           f"in trial {trial} at t = {t:.6g} s{self._reason()}",
                                           Status(max(error.status, Status.DISCARD)), trials=(trial,))
                raise self.failure from None

    def publish_initial(self) -> None:
        """Enter the FMUs' initialization mode and publish their initial outputs, as the native plant does
        (the master feeds components earlier in the order before this one initializes)."""
        t0, stop = self.start_time, self.stop_time
        try:
            self._set("parameter", "input")
            self._each("fmi2SetupExperiment", t0, lambda fmu: fmu.setupExperiment(startTime=t0, stopTime=stop))
            self._each("fmi2EnterInitializationMode", t0, lambda fmu: fmu.enterInitializationMode())
            self._get(t0)
        except StepFailure as failure:  # reported when initialization ends, where the master looks
            self.failure = failure

    def initialize(self) -> None:
        if self.failure is not None:
            raise self.failure
        self._set("parameter", "input")  # FMI allows both in initialization mode: take the latest
        self._each("fmi2ExitInitializationMode", self.start_time, lambda fmu: fmu.exitInitializationMode())
        self._get(self.start_time)

    def step(self, t: float, h: float) -> None:
        self._set("input")
        self._each("fmi2DoStep", t, lambda fmu: fmu.fmi2DoStep(fmu.component, t, h, 1))
        self._get(t + h)

    def terminate_hook(self) -> None:
        for fmu in self.instances:
            try:  # a failed FMU may only be freed; a healthy one in initialization or step mode terminates
                if self.failure is None and self.state in (INITIALIZATION, STEPPING):
                    fmu.terminate()
                fmu.freeInstance()
            except Exception:
                pass
        self.instances = []
