"""The FMI 2.0 initialization sequence of every component of a system, in step order."""
from __future__ import annotations

from rhi.master.cosim.errors import ConfigError, SimulationError
from rhi.master.cosim.links import Links
from rhi.master.cosim.system import System, split


def initialize(system: System, links: Links, batch_size: int, start_time: float, stop_time: float,
               parameters: dict) -> None:
    """Bring every component from created to step mode.

    instantiate(B) -> set parameters -> setup_experiment -> enter_initialization_mode, for all
    components; then, one component at a time in step order, set its inputs from the outputs
    already there (a later source without output leaves the start value) and
    exit_initialization_mode, so that initial outputs flow forward.

    Parameters
    ----------
    system : System
        A validated system.
    links : Links
        Its connections, resolved.
    batch_size : int
        B, the number of independent trials each component holds.
    start_time, stop_time : float
        Seconds, passed to ``setup_experiment``.
    parameters : dict
        ``{"component.variable": value}``, a scalar, or one value per trial (shape (B, *shape)).

    Raises
    ------
    ConfigError
        An input has no value at initialization (no start value, and its source comes later).
    SimulationError
        A component failed its initialization (named, at ``start_time``).
    """
    components = list(system.components.values())
    for component in components:
        component.instantiate(batch_size)
    for path, value in parameters.items():
        name, variable = split(path)
        system.components[name].set(variable, value)
    for component in components:
        component.setup_experiment(start_time, stop_time)
        component.enter_initialization_mode()
    for inputs in links.inputs:  # in order, so initial outputs flow forward
        component = inputs.component
        inputs.set()
        missing = [f"{component.name}.{v.name}" for v in component.variables.values()
                   if v.causality == "input" and v.name not in component.values]
        if missing:
            raise ConfigError(f"input {missing[0]} has no value at initialization: its source comes later "
                              "in the order and it has no start value (reorder the components)")
        component.exit_initialization_mode()
        if component.last_reason:
            raise SimulationError(component.name, start_time, component.last_reason, "initialization")
