"""The fixed-step master algorithm: a :class:`~rhi.master.cosim.session.Session` stepped on an integer tick counter."""
from __future__ import annotations

import math
import numpy as np

from rhi.master.cosim.errors import ConfigError
from rhi.master.cosim.session import Result, Session, check_request  # noqa: F401 (re-exported: their old home)
from rhi.master.cosim.system import System


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


def simulate(system: System, stop_time: float, step_size: float = 0.02, start_time: float = 0.0,
             scheme: str = "gauss-seidel", batch_size: int = 1, parameters: dict | None = None,
             record: list[str] = (), progress=None) -> Result:
    """Run ``system`` from ``start_time`` to ``stop_time`` in fixed steps and return what was recorded.

    A :class:`~rhi.master.cosim.session.Session` stepped over the integer tick grid :func:`tick_times`.

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
    times = tick_times(start_time, stop_time, steps)
    ticks = times.tolist()
    session = Session(system, start_time, stop_time, scheme, batch_size, parameters, record)
    try:
        for tick in range(steps):
            session.step(ticks[tick + 1] - ticks[tick], start=ticks[tick])
            if progress is not None:
                progress(tick + 1, steps)
    finally:
        session.close()
    return session.result(times, step_size)
