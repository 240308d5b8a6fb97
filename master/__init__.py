"""The master: a co-simulation engine (``rhi.master.cosim``) and what is built on it.

The one obvious call::

    from rhi.master import System, simulate
    result = simulate(System([a, b], [("a.y", "b.u")]), stop_time=30.0, step_size=0.02)

Sub-packages, imports going one way (docs/architecture.md; tests/test_layering.py enforces it):
``commands`` -> ``reference`` -> ``phenomena``, ``fit`` -> ``sweeps``, ``bench`` -> ``export`` -> ``tasks`` ->
``decoders`` -> ``config`` -> ``models`` -> ``runtime`` -> ``outputs`` -> ``cosim`` -> ``components``; no import circle.
"""
from rhi.master.cosim import ConfigError, Connection, Result, SimulationError, System, simulate

__all__ = ["System", "Connection", "simulate", "Result", "ConfigError", "SimulationError"]
