"""The master: wires components into a system and runs it at a fixed step.

The one obvious call::

    from master import System, simulate
    result = simulate(System([a, b], [("a.y", "b.u")]), stop_time=30.0, step_size=0.02)
"""
from master.algorithm import Result, simulate
from master.errors import ConfigError, SimulationError
from master.system import Connection, System

__all__ = ["System", "Connection", "simulate", "Result", "ConfigError", "SimulationError"]
