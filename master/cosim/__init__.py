"""A fixed-step co-simulation engine for FMI-style components; it knows nothing of any model.

A :class:`System` is components plus connections (output -> input), validated before it runs;
:func:`simulate` runs it at a fixed step, Jacobi or Gauss-Seidel, and returns a :class:`Result`;
a :class:`Session` is the same run one step at a time, for an outer master that owns the clock.

Modules, each one job: ``system`` (components, connections, validation), ``links`` (connections
resolved into per-component input setters), ``initialization`` (the FMI initialization sequence),
``recorder`` (recorded outputs per tick), ``session`` (:class:`Session`: validate, initialize once, then
per :meth:`~Session.step` set inputs, step, check the status, record; terminate in any case), ``loop``
(:func:`simulate`: a session stepped over the tick grid), ``errors``.
"""
from rhi.master.cosim.errors import ConfigError, SimulationError
from rhi.master.cosim.initialization import initialize
from rhi.master.cosim.links import Inputs, Links
from rhi.master.cosim.loop import simulate, step_count, tick_times
from rhi.master.cosim.session import Result, Session
from rhi.master.cosim.recorder import Recorder
from rhi.master.cosim.system import Connection, System

__all__ = ["System", "Connection", "simulate", "Session", "step_count", "tick_times", "Result", "ConfigError",
           "SimulationError", "Links", "Inputs", "Recorder", "initialize"]
