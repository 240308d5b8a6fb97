"""Any FMI 2.0 co-simulation FMU as a native component, on top of fmpy.

:class:`FMUComponent` reads the FMU's model description and declares one
:class:`~rhi.components.variables.Variable` per scalar Real, Integer or Boolean
variable (causality, unit, start, range, description and the output
dependencies of ``ModelStructure``), so the master validates and wires an FMU
exactly like a component written in Python. A batch of B trials is B FMU
instances; ``do_step`` steps each of them.

Before anything runs, :func:`check_contract` checks the file against a
contract (for a body, :data:`rhi.components.body.contract.BODY_CONTRACT`, docs/design.md "Body FMU
contract") and
the constructor raises one ComponentError that lists every problem found.

Every call into an FMU runs under a wall-clock limit (``step_timeout``, seconds; None: none) and with
SIGINT and SIGTERM kept out of the FMU's own code (:class:`~rhi.components.fmu.watchdog.Watch`): a call over its limit is stopped and
fails its trial with a StepFailure naming the FMU, the call, the trial and the time; a signal received
during a call stops the call, and then takes its usual course (KeyboardInterrupt) once the call has
returned, instead of being turned by the FMU into a failed step.

Example::

    body = FMUComponent("Body.fmu", "body", BODY_CONTRACT)
    system = System([..., brain, body], [("brain.u_shoulder", "body.u_shoulder"), ...])
"""
from __future__ import annotations

import collections
import os
import sys
import time
import zipfile

import numpy as np

from ..component import INITIALIZATION, STEPPING, Component, ComponentError, Status, StepFailure
from .contract import SCALAR_TYPES, CAUSALITY, check_contract, library_path
from .library import extracted, guard_library
from .watchdog import WATCH, Call, CallStopped
from ..variables import Variable


def _parse(kind: str, text):
    if text is None:
        return None
    if kind == "Boolean":
        return text in ("true", "1")
    return int(text) if kind == "Integer" else float(text)


class FMUComponent(Component):
    """An FMI 2.0 co-simulation FMU behaving as a native component.

    path: the .fmu file. name: instance name in the system.
    contract: the ContractVariables the FMU must have (empty: check only that it is a usable FMU), e.g.
    :data:`rhi.components.body.contract.BODY_CONTRACT`.
    step_timeout: seconds one call into an instance may take (None or 0: no limit); a longer call
    fails its trial (see the module's docstring).
    """

    def __init__(self, path, name: str, contract=(), step_timeout: float | None = None):
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
        """Instantiate one FMU instance per trial (fmi2Instantiate, one logger for all into ``messages``), with the
        signal handlers of :data:`~rhi.components.fmu.watchdog.WATCH` installed until :meth:`terminate`.

        Parameters
        ----------
        batch_size : int
            B, the trials.

        Raises
        ------
        ComponentError
            An instance could not be made (the FMU's messages give the reason).
        """
        from fmpy.fmi1 import calloc, free
        from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
        super().instantiate(batch_size)
        unzipdir, identifier = extracted(self.path), self.description.coSimulation.modelIdentifier
        guard_library(unzipdir, identifier)
        WATCH.attach()
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

        call = Call(self.label, "fmi2Instantiate", 0.0, None)  # no limit: the first one loads the FMU's code
        WATCH.begin(call)
        try:
            for trial in range(self.batch_size):
                if self._guarded(call, trial, lambda: make(trial)) is not None:
                    raise RuntimeError("stopped")
        except Exception as error:
            raise ComponentError(f"{self.name}: {self.label} could not be instantiated: {error}"
                                 f"{self._reason()}") from None
        finally:
            WATCH.end()
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

    def _guarded(self, call: Call, trial: int, function):
        """``function()``, a call into instance ``trial``, watched (see :class:`~rhi.components.fmu.watchdog.Watch`): returns None, or the
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
            WATCH.deliver(number)
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
        call = Call(self.label, what, t, self.step_timeout)
        WATCH.begin(call)
        try:
            for trial, fmu in enumerate(self.instances):
                status = self._guarded(call, trial, lambda: action(fmu))
                if status is not None:
                    self.failure = StepFailure(f"{self.label}: {what} returned {Status(status).name.lower()} "
                                               f"in trial {trial} at t = {t:.6g} s{self._reason()}",
                                               Status(max(status, Status.DISCARD)), trials=(trial,))
                    raise self.failure
        finally:
            WATCH.end()

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
        """Set the parameters and inputs, exit the instances' initialization mode and read their outputs at the start
        time; a failure met in :meth:`publish_initial` is raised here.
        """
        if self.failure is not None:
            raise self.failure
        self._set("parameter", "input")  # FMI allows both in initialization mode: take the latest
        self._each("fmi2ExitInitializationMode", self.start_time, lambda fmu: fmu.exitInitializationMode())
        self._get(self.start_time)

    def step(self, t: float, h: float) -> None:
        """Set the inputs, call fmi2DoStep on every instance and read the outputs at ``t + h``; a call that fails or
        runs over ``step_timeout`` fails its trial (StepFailure).

        Parameters
        ----------
        t, h : float
            The step's start and size, s.
        """
        self._set("input")
        self._each("fmi2DoStep", t, lambda fmu: fmu.fmi2DoStep(fmu.component, t, h, 1))
        self._get(t + h)

    def terminate_hook(self) -> None:
        """Terminate (a healthy instance that was initialized) and free every instance, whatever each answers, and
        release the signal handlers.
        """
        def release(fmu):  # a failed FMU may only be freed; a healthy one in initialization or step mode terminates
            if self.failure is None and self.state in (INITIALIZATION, STEPPING):
                fmu.terminate()
            fmu.freeInstance()

        call = Call(self.label, "fmi2Terminate", self.stop_time or 0.0, None)
        WATCH.begin(call)
        try:
            for trial, fmu in enumerate(self.instances):
                try:
                    self._guarded(call, trial, lambda: release(fmu))
                except Exception:  # noqa: BLE001: releasing what is left, whatever it says
                    pass
        finally:
            WATCH.end()
            self.instances = []
            if getattr(self, "_attached", False):
                self._attached = False
                WATCH.detach()
