"""Any FMI 2.0 co-simulation FMU as a native component, on top of fmpy.

:class:`FMUComponent` reads the FMU's model description and declares one
:class:`~components.variables.Variable` per scalar Real, Integer or Boolean
variable (causality, unit, start, range, description and the output
dependencies of ``ModelStructure``), so the master validates and wires an FMU
exactly like a component written in Python. A batch of B trials is B FMU
instances; ``do_step`` steps each of them.

Before anything runs, :func:`check_contract` checks the file against a
contract (by default :data:`BODY_CONTRACT`, docs/design.md "Body FMU contract") and
the constructor raises one ComponentError that lists every problem found.

Every call into an FMU runs under a wall-clock limit (``step_timeout``, seconds; None: none) and with
SIGINT and SIGTERM kept out of the FMU's own code (:class:`_Watch`): a call over its limit is stopped and
fails its trial with a StepFailure naming the FMU, the call, the trial and the time; a signal received
during a call stops the call, and then takes its usual course (KeyboardInterrupt) once the call has
returned, instead of being turned by the FMU into a failed step.

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
import signal
import sys
import tempfile
import threading
import time
import zipfile
from dataclasses import dataclass
from xml.etree import ElementTree as ET

import numpy as np

from components.archives import ArchiveError, check_archive, extract
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
    """The FMU at ``path`` unzipped (checked: :func:`components.archives.extract`), once per process and
    file version (removed at exit)."""
    status = os.stat(path)
    key = (path, status.st_mtime_ns, status.st_size)
    if key not in _EXTRACTED:
        folder = tempfile.mkdtemp(prefix="rhi_fmu_")
        try:
            extract(path, folder)
        except BaseException:
            shutil.rmtree(folder, ignore_errors=True)
            raise
        _EXTRACTED[key] = folder
    return _EXTRACTED[key]


@atexit.register
def _release() -> None:
    for library in filter(None, _GUARDED.values()):
        library.finalizePythonInterpreter()
    for folder in _EXTRACTED.values():
        shutil.rmtree(folder, ignore_errors=True)


# -- time limits and signals during calls into an FMU ------------------------------------------------
class CallStopped(Exception):
    """Raised inside a call into an FMU (a pythonfmu slave runs Python in the calling thread) to end it:
    it is over its time limit, or the process received SIGINT or SIGTERM. The FMU fails the call."""


def _default_on_stuck(message: str) -> None:
    sys.stderr.write(message + "\n")
    sys.stderr.flush()
    os._exit(1)


# Called (from the watchdog thread) with a one-line message when a call has not returned long after its
# limit and cannot be stopped (it runs native code that never returns to Python); it must end the
# process. The command line replaces it to remove its staging folder first.
on_stuck = _default_on_stuck


def _grace(limit: float) -> float:
    """Seconds past the limit before a call that ignores being stopped counts as stuck for good."""
    return min(max(limit, 2.0), 10.0)


class _Call:
    """One component's calls into its FMU instances, under way in the main thread (at most one at a time)."""

    __slots__ = ("label", "what", "t", "trial", "limit", "started", "inside", "overdue", "signal", "next_kick")

    def __init__(self, label: str, what: str, t: float, limit: float | None):
        self.label, self.what, self.t, self.limit = label, what, t, limit
        self.trial, self.started, self.inside, self.overdue, self.signal, self.next_kick = 0, 0.0, False, False, None, 0.0


class _Watch:
    """SIGINT, SIGTERM and SIGALRM handlers (main thread) and one watchdog thread, for FMU calls.

    While a call is inside the FMU, SIGINT/SIGTERM raise CallStopped there (so the FMU fails the call
    cleanly, as with any exception of its own) and are remembered; the adapter takes them up when the
    call has returned. Outside a call they go to the handlers that were there before. The watchdog
    thread sends SIGALRM to the main thread when a call passes its limit (again every second), which
    raises CallStopped inside it; a call still running ``_grace`` seconds later is stuck in native code,
    and ``on_stuck`` ends the process. Calls from other threads get only the watchdog's last resort.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self.users = 0
        self.previous: dict[int, object] = {}
        self.calls: dict[int, _Call] = {}  # thread ident -> its call in progress
        self.thread = None

    # handlers: installed while any FMUComponent is instantiated in the main thread
    def attach(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        if self.users == 0:
            for number in (*self.SIGNALS, signal.SIGALRM):
                previous = signal.getsignal(number)
                self.previous[number] = signal.SIG_DFL if previous is None else previous
                signal.signal(number, self._on_signal)
        self.users += 1

    def detach(self) -> None:
        if threading.current_thread() is not threading.main_thread() or self.users == 0:
            return
        self.users -= 1
        if self.users == 0:
            for number, previous in self.previous.items():
                if signal.getsignal(number) == self._on_signal:
                    signal.signal(number, previous)
            self.previous.clear()

    def _on_signal(self, number, frame):
        call = self.calls.get(threading.main_thread().ident)
        if number == signal.SIGALRM:
            if call is not None and call.inside and call.overdue:
                raise CallStopped(f"over the time limit of {call.limit:g} s")
            return self._pass_on(number, frame)
        if call is not None and call.inside:
            call.signal = number
            raise CallStopped(f"interrupted by {signal.Signals(number).name}")
        return self._pass_on(number, frame)

    def _pass_on(self, number, frame):
        """What the signal would have done without us."""
        previous = self.previous.get(number, signal.SIG_DFL)
        if callable(previous):
            return previous(number, frame)
        if previous == signal.SIG_IGN or number == signal.SIGALRM:
            return None
        signal.signal(number, signal.SIG_DFL)  # the default action (ends the process)
        signal.raise_signal(number)

    def deliver(self, number: int) -> None:
        """Take up a signal that arrived during a call, now that the call has returned."""
        self._pass_on(number, None)

    # the calls, and the watchdog thread
    def begin(self, call: _Call) -> None:
        self.calls[threading.get_ident()] = call
        if call.limit and (self.thread is None or not self.thread.is_alive()):
            self.thread = threading.Thread(target=self._watch, name="rhi-fmu-watchdog", daemon=True)
            self.thread.start()

    def end(self) -> None:
        self.calls.pop(threading.get_ident(), None)

    def _watch(self) -> None:
        main = threading.main_thread().ident
        idle_since = time.monotonic()
        while True:
            time.sleep(0.05)
            now = time.monotonic()
            calls = list(self.calls.items())
            if not calls:
                if now - idle_since > 5.0:  # started again by the next call that has a limit
                    self.thread = None
                    return
                continue
            idle_since = now
            for ident, call in calls:
                if not call.limit or not call.inside:
                    continue
                over = now - call.started - call.limit
                if over < 0:
                    continue
                call.overdue = True
                if over > _grace(call.limit):
                    on_stuck(f"{call.label}: {call.what} in trial {call.trial} at t = {call.t:.6g} s has not "
                             f"returned after {now - call.started:.0f} s (time limit {call.limit:g} s) and cannot "
                             "be stopped (it runs native code that does not return); ending the process")
                elif ident == main and now >= call.next_kick and self.users:
                    call.next_kick = now + 1.0
                    signal.pthread_kill(main, signal.SIGALRM)


_WATCH = _Watch()


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
    step_timeout: seconds one call into an instance may take (None or 0: no limit); a longer call
    fails its trial (see the module's docstring).
    """

    def __init__(self, path, name: str = "body", contract=BODY_CONTRACT, step_timeout: float | None = None):
        from fmpy import read_model_description
        self.step_timeout = float(step_timeout) if step_timeout else None
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
        self._load(name)
        super().__init__(name, self._declare())
        self.instances, self.messages, self.failure = [], collections.deque(maxlen=20), None

    def _load(self, name: str) -> None:
        """Unzip the FMU and load its binary now, so that a library this machine cannot load is refused
        before any work (ComponentError naming the file and the loader's reason)."""
        identifier, unzipdir = self.description.coSimulation.modelIdentifier, ""
        try:
            unzipdir = extracted(self.path)
            guard_library(unzipdir, identifier)
        except (OSError, zipfile.BadZipFile, ValueError) as error:
            reason = " ".join(str(error).split()).replace(os.fspath(unzipdir) + os.sep, "") or type(error).__name__
            raise ComponentError(f"{name}: {os.path.basename(self.path)} cannot be used: its binary "
                                 f"{library_path('', identifier).lstrip(os.sep)} does not load on this machine "
                                 f"({reason})") from None

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
        _WATCH.attach()
        self._attached = True
        self._callbacks = fmi2CallbackFunctions()  # one logger for all: FMU messages explain failures
        self._callbacks.logger = fmi2CallbackLoggerTYPE(
            lambda env, instance, status, category, message: self.messages.append(
                (message or b"").decode("utf-8", "replace").strip()))
        self._callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self._callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        saved_path = list(sys.path)  # a pythonfmu FMU prepends its resources to sys.path for good

        def make(trial):
            fmu = FMU2Slave(guid=self.description.guid, unzipDirectory=unzipdir,
                            modelIdentifier=identifier, instanceName=f"{self.name}[{trial}]")
            fmu.instantiate(callbacks=self._callbacks, loggingOn=True)
            self.instances.append(fmu)

        call = _Call(self.label, "fmi2Instantiate", 0.0, None)  # no limit: the first one loads the FMU's code
        _WATCH.begin(call)
        try:
            for trial in range(self.batch_size):
                if self._guarded(call, trial, lambda: make(trial)) is not None:
                    raise RuntimeError("stopped")
        except Exception as error:
            raise ComponentError(f"{self.name}: {self.label} could not be instantiated: {error}"
                                 f"{self._reason()}") from None
        finally:
            _WATCH.end()
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

    def _guarded(self, call: _Call, trial: int, function):
        """``function()``, a call into instance ``trial``, watched (see :class:`_Watch`): returns None, or the
        FMI status of a call that failed; a call over the limit raises a StepFailure for its trial; a signal
        received during the call takes its usual course once it has returned."""
        from fmpy.fmi1 import FMICallException
        status, other = None, None
        call.trial, call.started, call.overdue, call.inside = trial, time.monotonic(), False, True
        try:
            function()
        except FMICallException as error:
            status = error.status
        except CallStopped:  # it came just before or after the FMU's own code ran
            status = Status.ERROR
        except Exception as error:  # noqa: BLE001: raised again below, once a signal has been taken up
            other = error
        finally:
            call.inside = False
        if call.signal is not None:  # SIGINT/SIGTERM during the call: the usual course now (KeyboardInterrupt)
            number, call.signal = call.signal, None
            self.failure = self.failure or StepFailure(f"{self.label}: {call.what} interrupted in trial {trial}")
            _WATCH.deliver(number)
        if call.overdue and call.limit:
            self.messages.clear()
            self.failure = StepFailure(
                f"{self.label}: {call.what} did not return within its time limit of {call.limit:g} s in trial "
                f"{trial} at t = {call.t:.6g} s (stopped after {time.monotonic() - call.started:.1f} s)",
                Status.ERROR, trials=(trial,))
            raise self.failure
        if other is not None:
            raise other
        return status

    def _each(self, what: str, t: float, action) -> None:
        """Run ``action(fmu)`` on every instance; a status worse than warning becomes a StepFailure, and so
        does a call over the time limit; a signal received during a call is taken up once it has returned."""
        call = _Call(self.label, what, t, self.step_timeout)
        _WATCH.begin(call)
        try:
            for trial, fmu in enumerate(self.instances):
                status = self._guarded(call, trial, lambda: action(fmu))
                if status is not None:
                    self.failure = StepFailure(f"{self.label}: {what} returned {Status(status).name.lower()} "
                                               f"in trial {trial} at t = {t:.6g} s{self._reason()}",
                                               Status(max(status, Status.DISCARD)), trials=(trial,))
                    raise self.failure
        finally:
            _WATCH.end()

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
        def release(fmu):  # a failed FMU may only be freed; a healthy one in initialization or step mode terminates
            if self.failure is None and self.state in (INITIALIZATION, STEPPING):
                fmu.terminate()
            fmu.freeInstance()

        call = _Call(self.label, "fmi2Terminate", self.stop_time or 0.0, None)
        _WATCH.begin(call)
        try:
            for trial, fmu in enumerate(self.instances):
                try:
                    self._guarded(call, trial, lambda: release(fmu))
                except Exception:  # noqa: BLE001: releasing what is left, whatever it says
                    pass
        finally:
            _WATCH.end()
            self.instances = []
            if getattr(self, "_attached", False):
                self._attached = False
                _WATCH.detach()
