"""A fixed-step co-simulation engine for FMI-style components; it knows nothing of any model.

A :class:`System` is components plus connections (output -> input), validated before it runs;
:func:`simulate` runs it at a fixed step, Jacobi or Gauss-Seidel, and returns a :class:`Result`.
"""
from master.cosim.errors import ConfigError, SimulationError
from master.cosim.loop import Result, simulate, step_count
from master.cosim.system import Connection, System

__all__ = ["System", "Connection", "simulate", "step_count", "Result", "ConfigError", "SimulationError"]
