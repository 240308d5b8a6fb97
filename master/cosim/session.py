"""A system initialized once and then stepped one communication step at a time.

:class:`Session` is the master algorithm's one loop body: it validates the request, runs the FMI
initialization sequence (:func:`~rhi.master.cosim.initialization.initialize`) once, and then each
:meth:`Session.step` sets the connected inputs (Jacobi or Gauss-Seidel), steps every component in
order, checks its status and records. :func:`~rhi.master.cosim.loop.simulate` is a session stepped
over a fixed grid of ticks; an outer master that owns the clock (an FMU's ``fmi2DoStep``) steps a
session with the times it is given.

Example::

    with Session(system, parameters={"source.value": 1.0}, record=["sink.y"]) as session:
        session.set("sink.outside", 2.0)      # an input no connection feeds
        session.step(0.02)                    # t = 0 -> 0.02
        session.step(0.02)                    # t = 0.02 -> 0.04
        y = session.get("sink.y")
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from rhi.components.component import ComponentError, Status
from rhi.master.cosim.errors import ConfigError, SimulationError
from rhi.master.cosim.initialization import initialize
from rhi.master.cosim.links import Links
from rhi.master.cosim.recorder import Recorder
from rhi.master.cosim.system import System, split


@dataclass
class Result:
    """What a run recorded.

    Attributes
    ----------
    times : numpy.ndarray
        (steps + 1,) seconds, the communication points.
    values : dict
        ``path -> array`` of shape (steps + 1, B, *shape); row 0 holds the initial values.
    scheme, step_size, batch_size :
        As run.
    timings : dict
        Seconds: ``total_s``, ``setup_s`` (instantiation to the first recorded row),
        ``master_overhead_s`` (the stepping the components did not spend) and ``step_s.NAME`` per component.
    """

    times: np.ndarray
    values: dict[str, np.ndarray]
    scheme: str
    step_size: float
    batch_size: int
    timings: dict[str, float] = field(default_factory=dict)


def check_request(system: System, scheme: str, record, parameters: dict) -> None:
    """Check a run before anything starts.

    Parameters
    ----------
    system : System
        The system to run.
    scheme : str
        ``"gauss-seidel"`` or ``"jacobi"``.
    record : iterable of str
        Paths to record: each must be an output or a local.
    parameters : dict
        ``{"component.variable": value}``: each path must be a parameter.

    Raises
    ------
    ConfigError
        Naming the problem: a bad system (:meth:`System.validate`), a recorded path that is not an
        output, a parameter path that is not a parameter.
    """
    system.validate(scheme)
    for path in record:
        variable = system.variable(path)
        if variable.causality not in ("output", "local"):
            raise ConfigError(f"cannot record {path}: it is an {variable.causality}, not an output")
    for path in parameters:
        if system.variable(path).causality != "parameter":
            raise ConfigError(f"{path} is not a parameter")


class Session:
    """A validated, initialized system that advances one communication step per :meth:`step`.

    Verbs: :meth:`step`, :meth:`set` (an input no connection feeds), :meth:`get`, :meth:`result`,
    :meth:`close` (also on leaving a ``with`` block).

    Parameters
    ----------
    system : System
        Components in Gauss-Seidel order, and their connections.
    start_time : float
        Seconds; the time of the first step's start.
    stop_time : float or None
        Seconds, passed to every component's ``setup_experiment`` (None: open-ended).
    scheme : str
        ``"gauss-seidel"`` (each component reads the newest outputs) or ``"jacobi"`` (the outputs at t).
    batch_size : int
        B independent trials advancing together.
    parameters : dict, optional
        ``{"component.variable": value}`` set before initialization; a scalar or one value per trial.
    record : list of str
        Output paths recorded after initialization and after every step.

    Raises
    ------
    ConfigError
        Before anything runs: a bad system, path or parameter (:func:`check_request`).
    SimulationError
        A component failed its initialization; every component has been terminated.

    Attributes
    ----------
    time : float
        Seconds: the end of the last step (``start_time`` before the first).
    steps : int
        Steps taken.
    """

    def __init__(self, system: System, start_time: float = 0.0, stop_time: float | None = None,
                 scheme: str = "gauss-seidel", batch_size: int = 1, parameters: dict | None = None,
                 record=()):
        parameters = dict(parameters or {})
        check_request(system, scheme, record, parameters)
        self.system, self.scheme, self.batch_size = system, scheme, batch_size
        self.links, self.recorder = Links(system), Recorder(system, record)
        self._stages = self.links.inputs  # one per component, in step order
        self._spent = [0.0] * len(self._stages)
        self._external = {path for path, variable in self._inputs() if path not in system.feeds()}
        self.time, self.steps, self.closed = float(start_time), 0, False
        self._times = [float(start_time)]
        self._started = time.perf_counter()
        try:
            initialize(system, self.links, batch_size, start_time, stop_time, parameters)
            self.recorder.record()
        except BaseException:
            self.close()
            raise
        self.setup_seconds = time.perf_counter() - self._started

    def _inputs(self):
        for name, component in self.system.components.items():
            for variable in component.variables.values():
                if variable.causality == "input":
                    yield f"{name}.{variable.name}", variable

    def step(self, step_size: float, start: float | None = None) -> None:
        """Advance every component by one communication step.

        Parameters
        ----------
        step_size : float
            Seconds, h > 0.
        start : float, optional
            Seconds, the step's start t (default: :attr:`time`, the end of the last step); an outer
            master that owns the clock passes its own.

        Raises
        ------
        SimulationError
            A component failed the step: its name, t, its reason and the trials it blamed. The
            session stays open; :meth:`close` terminates it.
        """
        if self.closed:
            raise ConfigError("the session is closed: it cannot step")
        t = self.time if start is None else float(start)
        snapshot = self.links.snapshot() if self.scheme == "jacobi" else None
        for index, inputs in enumerate(self._stages):
            inputs.set(snapshot)
            component = inputs.component
            began = time.perf_counter()
            try:
                status = component.do_step(t, step_size)
            except (MemoryError, ComponentError):  # the machine's, or a refusal of the input: as they are
                raise
            except Exception as error:  # noqa: BLE001: a component's own code (a user's model's) failed
                raise SimulationError(component.name, t, f"{type(error).__name__}: {error}", "error") from error
            self._spent[index] += time.perf_counter() - began
            if status >= Status.DISCARD:
                raise SimulationError(component.name, t, component.last_reason or "no reason given",
                                      status.name.lower(), component.failed_trials)
        self.time, self.steps = t + step_size, self.steps + 1
        self._times.append(self.time)
        self.recorder.record()

    def set(self, path: str, value) -> None:
        """Set an input that no connection feeds (the outside world's), for the steps that follow.

        Parameters
        ----------
        path : str
            ``component.variable``, an input without a connection.
        value : scalar or array
            One value for every trial, or one per trial (shape (B, *shape)).

        Raises
        ------
        ConfigError
            ``path`` is not such an input (a connected input is set by its source).
        """
        if path not in self._external:
            variable = self.system.variable(path)
            raise ConfigError(f"{path} is {'fed by a connection' if variable.causality == 'input' else 'an ' + variable.causality}"
                              "; only an input that no connection feeds can be set from outside")
        name, variable = split(path)
        self.system.components[name].set(variable, value)

    def get(self, path: str):
        """The current value at ``path`` (``component.variable``): an array of shape (B, *shape)."""
        self.system.variable(path)
        name, variable = split(path)
        return self.system.components[name].get(variable)

    def result(self, times=None, step_size: float | None = None):
        """What was recorded so far, as a :class:`Result`.

        Parameters
        ----------
        times : array, optional
            The communication points to report (default: the session's own, t + h after each step).
        step_size : float, optional
            Seconds, reported as the Result's step size.
        """
        total = time.perf_counter() - self._started
        spent = sum(self._spent)
        timings = {"total_s": total, "setup_s": self.setup_seconds,
                   "master_overhead_s": total - self.setup_seconds - spent,
                   **{f"step_s.{inputs.component.name}": seconds for inputs, seconds in zip(self._stages, self._spent)}}
        return Result(np.asarray(self._times if times is None else times), self.recorder.arrays(), self.scheme,
                      step_size, self.batch_size, timings)

    def close(self) -> None:
        """Terminate every component (whatever state it is in); a closed session cannot step."""
        self.closed = True
        for component in self.system.components.values():
            component.terminate()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
