"""The fixed-step master algorithm: Jacobi or Gauss-Seidel on an integer tick counter."""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from components.component import Status
from master.cosim.errors import ConfigError, SimulationError
from master.cosim.initialization import initialize
from master.cosim.links import Links
from master.cosim.recorder import Recorder
from master.cosim.system import System


def step_count(start_time: float, stop_time: float, step_size: float) -> int:
    """The number of communication steps from ``start_time`` to ``stop_time``.

    Parameters
    ----------
    start_time, stop_time, step_size : float
        Seconds; finite, ``step_size > 0`` and ``stop_time > start_time``.

    Returns
    -------
    int
        N, such that N steps of ``step_size`` span the interval (to 1e-9 relative).

    Raises
    ------
    ConfigError
        A bad number, or an interval that is not a whole number of steps.
    """
    for name, value in (("step size", step_size), ("start time", start_time), ("stop time", stop_time)):
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
            raise ConfigError(f"{name} must be a finite number, got {value!r}")
    if step_size <= 0:
        raise ConfigError(f"step size must be positive, got {step_size!r}")
    if stop_time <= start_time:
        raise ConfigError(f"stop time {stop_time!r} must be after start time {start_time!r}")
    steps = round((stop_time - start_time) / step_size)
    if abs(steps * step_size - (stop_time - start_time)) > 1e-9 * max(1.0, stop_time - start_time):
        raise ConfigError(f"stop time {stop_time!r} is not a whole number of steps of {step_size!r} s "
                          f"after start time {start_time!r}")
    return steps


def tick_times(start_time: float, stop_time: float, steps: int) -> np.ndarray:
    """The communication points ``t_n = start + (stop - start) * n / N``, n = 0 .. N.

    Returns
    -------
    numpy.ndarray
        Shape (N + 1,), float64; the last is exactly ``stop_time``, whatever ``n * step_size`` would give.
    """
    return start_time + (stop_time - start_time) * np.arange(steps + 1) / steps


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
    """ConfigError naming the problem if the system, a recorded path or a parameter path is unusable."""
    system.validate(scheme)
    for path in record:
        variable = system.variable(path)
        if variable.causality not in ("output", "local"):
            raise ConfigError(f"cannot record {path}: it is an {variable.causality}, not an output")
    for path in parameters:
        if system.variable(path).causality != "parameter":
            raise ConfigError(f"{path} is not a parameter")


def simulate(system: System, stop_time: float, step_size: float = 0.02, start_time: float = 0.0,
             scheme: str = "gauss-seidel", batch_size: int = 1, parameters: dict | None = None,
             record: list[str] = (), progress=None) -> Result:
    """Run ``system`` from ``start_time`` to ``stop_time`` in fixed steps and return what was recorded.

    Parameters
    ----------
    system : System
        Components in Gauss-Seidel order, and their connections.
    stop_time, step_size, start_time : float
        Seconds; the interval must be a whole number of steps (:func:`step_count`).
    scheme : str
        ``"gauss-seidel"`` (each component reads the newest outputs) or ``"jacobi"`` (the outputs at t).
    batch_size : int
        B independent trials advancing together.
    parameters : dict, optional
        ``{"component.variable": value}`` set before initialization; a scalar or one value per trial.
    record : list of str
        Output paths recorded after initialization and after every step.
    progress : callable, optional
        ``progress(steps_done, steps_total)`` after every step.

    Returns
    -------
    Result
        ``values[path]`` of shape (steps + 1, B, *shape), and the timings.

    Raises
    ------
    ConfigError
        Before anything runs: a bad system, step, path or parameter.
    SimulationError
        A component failed a step: its name, the time t of the step's start and its reason.
    """
    steps = step_count(start_time, stop_time, step_size)
    parameters = dict(parameters or {})
    check_request(system, scheme, record, parameters)
    times = tick_times(start_time, stop_time, steps)
    ticks = times.tolist()
    links, recorder = Links(system), Recorder(system, record)
    stages = links.inputs  # one per component, in step order
    spent = [0.0] * len(stages)
    jacobi = scheme == "jacobi"
    started = time.perf_counter()
    try:
        initialize(system, links, batch_size, start_time, stop_time, parameters)
        recorder.record()
        setup_seconds = time.perf_counter() - started
        for tick in range(steps):
            t, h = ticks[tick], ticks[tick + 1] - ticks[tick]
            snapshot = links.snapshot() if jacobi else None
            for index, inputs in enumerate(stages):
                inputs.set(snapshot)
                component = inputs.component
                began = time.perf_counter()
                status = component.do_step(t, h)
                spent[index] += time.perf_counter() - began
                if status >= Status.DISCARD:
                    raise SimulationError(component.name, t, component.last_reason or "no reason given",
                                          status.name.lower(), component.failed_trials)
            recorder.record()
            if progress is not None:
                progress(tick + 1, steps)
    finally:
        for component in system.components.values():
            component.terminate()

    total = time.perf_counter() - started
    timings = {"total_s": total, "setup_s": setup_seconds, "master_overhead_s": total - setup_seconds - sum(spent),
               **{f"step_s.{inputs.component.name}": seconds for inputs, seconds in zip(stages, spent)}}
    return Result(times, recorder.arrays(), scheme, step_size, batch_size, timings)
