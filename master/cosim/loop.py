"""The fixed-step master algorithm: Jacobi or Gauss-Seidel on an integer tick counter."""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from components.component import Status
from master.cosim.errors import ConfigError, SimulationError
from master.cosim.system import System, split


def step_count(start_time: float, stop_time: float, step_size: float) -> int:
    """Number of communication steps; ConfigError unless (stop - start) is a whole number of steps."""
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


@dataclass
class Result:
    """Recorded outputs: ``values[path]`` has shape (steps + 1, B, *shape), row 0 the initial values."""

    times: np.ndarray
    values: dict[str, np.ndarray]
    scheme: str
    step_size: float
    batch_size: int
    timings: dict[str, float] = field(default_factory=dict)


def simulate(system: System, stop_time: float, step_size: float = 0.02, start_time: float = 0.0,
             scheme: str = "gauss-seidel", batch_size: int = 1, parameters: dict | None = None,
             record: list[str] = (), progress=None) -> Result:
    """Run ``system`` from ``start_time`` to ``stop_time`` in fixed steps and return what was recorded.

    parameters: ``{"component.variable": value}`` set before initialization.
    record: output paths recorded after initialization and after every step.
    progress: optional callable ``progress(steps_done, steps_total)``.

    Time at tick n is ``start + (stop - start) * n / N``, so the last tick is
    exactly ``stop_time`` whatever rounding ``n * step_size`` would give.
    """
    steps = step_count(start_time, stop_time, step_size)
    system.validate(scheme)
    for path in record:
        variable = system.variable(path)
        if variable.causality not in ("output", "local"):
            raise ConfigError(f"cannot record {path}: it is an {variable.causality}, not an output")
    parameters = dict(parameters or {})
    for path in parameters:
        if system.variable(path).causality != "parameter":
            raise ConfigError(f"{path} is not a parameter")

    components = list(system.components.values())
    # Resolve every connection once into (component, input name, source component, output name).
    links = {c.name: [] for c in components}
    for target, source in system.feeds().items():
        (target_name, target_var), (source_name, source_var) = split(target), split(source)
        links[target_name].append((target_var, system.components[source_name], source_var))
    recorded = [(path, system.components[split(path)[0]], split(path)[1]) for path in record]
    spent = {c.name: 0.0 for c in components}
    started = time.perf_counter()

    def set_inputs(component, outputs=None):
        for target_var, source, source_var in links[component.name]:
            value = outputs[(source.name, source_var)] if outputs is not None else source.values.get(source_var)
            if value is not None:  # at initialization a later source may have no output yet: keep the start
                component.set(target_var, value)

    try:
        for component in components:
            component.instantiate(batch_size)
        for path, value in parameters.items():
            name, variable = split(path)
            system.components[name].set(variable, value)
        for component in components:
            component.setup_experiment(start_time, stop_time)
            component.enter_initialization_mode()
        for component in components:  # in order, so initial outputs flow forward
            set_inputs(component)
            missing = [f"{component.name}.{v.name}" for v in component.variables.values()
                       if v.causality == "input" and v.name not in component.values]
            if missing:
                raise ConfigError(f"input {missing[0]} has no value at initialization: its source comes later "
                                  "in the order and it has no start value (reorder the components)")
            component.exit_initialization_mode()
            if component.last_reason:
                raise SimulationError(component.name, start_time, component.last_reason, "initialization")
        history = {path: [np.array(c.values[v], copy=True)] for path, c, v in recorded}
        setup_seconds = time.perf_counter() - started

        for tick in range(steps):
            t = start_time + (stop_time - start_time) * tick / steps
            h = start_time + (stop_time - start_time) * (tick + 1) / steps - t
            if scheme == "jacobi":
                # Every component reads the outputs as they were at t (a snapshot of references).
                outputs = {(source.name, source_var): source.values[source_var]
                           for c in components for _, source, source_var in links[c.name]}
            for component in components:
                set_inputs(component, outputs if scheme == "jacobi" else None)
                began = time.perf_counter()
                status = component.do_step(t, h)
                spent[component.name] += time.perf_counter() - began
                if status >= Status.DISCARD:
                    raise SimulationError(component.name, t, component.last_reason or "no reason given",
                                          status.name.lower(), component.failed_trials)
            for path, c, v in recorded:
                history[path].append(np.array(c.values[v], copy=True))
            if progress is not None:
                progress(tick + 1, steps)
    finally:
        for component in components:
            component.terminate()

    total = time.perf_counter() - started
    times = start_time + (stop_time - start_time) * np.arange(steps + 1) / steps
    timings = {"total_s": total, "setup_s": setup_seconds,
               "master_overhead_s": total - setup_seconds - sum(spent.values()),
               **{f"step_s.{name}": seconds for name, seconds in spent.items()}}
    return Result(times, {path: np.stack(rows) for path, rows in history.items()}, scheme, step_size,
                  batch_size, timings)
