"""The component model: FMI 2.0 co-simulation semantics, in Python.

A component declares its variables (:class:`~rhi.components.variables.Variable`) and
implements the hooks it needs; the base class owns the lifecycle, the checked
get/set by name, and the step status, so that every component, and an FMU wrapped
by an adapter, looks the same to the master:

    instantiate(batch_size) -> set parameters -> setup_experiment(start, stop)
    -> enter_initialization_mode() -> exit_initialization_mode()
    -> do_step(t, h) ... -> terminate()

Hooks, each called by the lifecycle verb named:

- :meth:`Component.publish_initial` (by ``enter_initialization_mode``, after the
  parameters are set): the outputs that follow from parameters and start values
  alone. FMI lets a master read outputs in initialization mode, and the master
  enters initialization mode on every component before it exits any, so a
  component earlier in the order reads them (the decoder reads the brain's mu0).
  Default: nothing.
- :meth:`Component.initialize` (by ``exit_initialization_mode``, with the inputs
  set): state and initial outputs.
- :meth:`Component.step` (by ``do_step``): advance one communication step.
- :meth:`Component.check_parameters` (by the component's own ``initialize``, and by a master
  before any work): the rules the parameters must meet beyond their declared ranges.
- :meth:`Component.terminate_hook` (by ``terminate``): release resources.

Values live in ``self.values`` as arrays with a leading batch dimension. A
component replaces its output arrays in ``step``; it never mutates them in
place, because the master hands the same array object to the inputs it feeds.
An output that is costly and often unread may be published as a :class:`Deferred`:
it is computed on its first read, as an FMU may compute an output in fmi2GetReal.

Example::

    class Gain(Component):
        def __init__(self, name="gain"):
            super().__init__(name, [
                Variable("k", "parameter", start=2.0, unit="1", description="gain"),
                Variable("u", "input", unit="1", description="signal in"),
                Variable("y", "output", unit="1", description="k * u"),
            ])
        def step(self, t, h):
            self.values["y"] = self.values["k"] * self.values["u"]
"""
from __future__ import annotations

import enum

import numpy as np

from .variables import Variable


class Status(enum.IntEnum):
    """FMI 2.0 status codes returned by :meth:`Component.do_step`."""

    OK = 0
    WARNING = 1
    DISCARD = 2
    ERROR = 3
    FATAL = 4


class StepFailure(Exception):
    """Raised inside :meth:`Component.step` to fail the step with a status and a reason."""

    def __init__(self, reason: str, status: Status = Status.ERROR, trials: tuple[int, ...] = ()):
        super().__init__(reason)
        self.reason = reason
        self.status = status
        self.trials = tuple(int(i) for i in trials)  # batch positions that failed; () = the whole batch


class ComponentError(ValueError):
    """Bad use of a component: unknown variable, wrong causality, bad value, wrong state.

    The message names the component and the variable; the command line shows it
    as one line and exits with status 2.
    """


class Deferred:
    """An output value computed on its first read: ``Deferred(lambda: ...)`` in place of the array.

    The function must capture what it needs at the step that publishes it; the next
    step replaces it (unread, it costs nothing).
    """

    __slots__ = ("compute",)

    def __init__(self, compute):
        self.compute = compute


class Values(dict):
    """A component's current values by name; a :class:`Deferred` one is computed when first read."""

    def __getitem__(self, name):
        value = dict.__getitem__(self, name)
        if type(value) is Deferred:
            value = value.compute()
            dict.__setitem__(self, name, value)
        return value

    def get(self, name, default=None):
        """The value of ``name`` (a :class:`Deferred` one computed), or ``default`` when there is none."""
        return self[name] if name in self else default


# Lifecycle states, in order.
CREATED, INSTANTIATED, INITIALIZATION, STEPPING, TERMINATED = (
    "created", "instantiated", "initialization mode", "step mode", "terminated")


class Component:
    """Base class of every co-simulation component.

    name: instance name, unique in a system.
    variables: the declared variables (see :mod:`rhi.components.variables`).
    """

    def __init__(self, name: str, variables: list[Variable]):
        self.name = name
        self.variables = {v.name: v for v in variables}
        if len(self.variables) != len(variables):
            raise ValueError(f"component {name!r} declares a variable twice")
        self.state = CREATED
        self.batch_size = 0
        self.values = Values()
        self.last_reason = ""
        self.failed_trials: tuple[int, ...] = ()
        self.start_time = 0.0
        self.stop_time: float | None = None

    # -- hooks for subclasses -------------------------------------------------
    def publish_initial(self) -> None:
        """Outputs that follow from parameters and start values alone, readable in initialization mode
        (before exit_initialization_mode); default: nothing.

        Parameters set later, in initialization mode, take effect in :meth:`initialize`.
        """

    def initialize(self) -> None:
        """Compute state and initial outputs from parameters and start values."""

    def check_parameters(self) -> None:
        """Raise ComponentError, naming the parameter, if the parameters set break a rule the declared
        ranges cannot state (a positive sd, one value for every trial, a hand within reach); needs no
        input, so a master calls it right after setting the parameters. Default: nothing."""

    def step(self, t: float, h: float) -> None:
        """Advance from ``t`` to ``t + h`` using the current inputs; raise StepFailure to fail."""
        raise NotImplementedError

    def terminate_hook(self) -> None:
        """Release resources (files, threads, native libraries)."""

    # -- lifecycle -------------------------------------------------------------
    def instantiate(self, batch_size: int = 1) -> None:
        """Allocate storage for ``batch_size`` independent trials, filled with start values."""
        if not isinstance(batch_size, (int, np.integer)) or batch_size < 1:
            raise ComponentError(f"{self.name}: batch_size must be a positive integer, got {batch_size!r}")
        self._require(CREATED, "instantiate")
        self.batch_size = int(batch_size)
        for var in self.variables.values():
            if var.start is not None:
                self.values[var.name] = self._coerce(var, var.start)
        self.state = INSTANTIATED

    def setup_experiment(self, start_time: float = 0.0, stop_time: float | None = None) -> None:
        """Set the run's start and stop times (instantiated components only).

        Parameters
        ----------
        start_time : float
            s; the time :meth:`exit_initialization_mode` initializes at.
        stop_time : float or None
            s; None: open-ended.
        """
        self._require(INSTANTIATED, "setup_experiment")
        self.start_time, self.stop_time = float(start_time), stop_time

    def enter_initialization_mode(self) -> None:
        """Enter initialization mode and call :meth:`publish_initial`; parameters may still be set."""
        self._require(INSTANTIATED, "enter_initialization_mode")
        self.state = INITIALIZATION
        self.publish_initial()

    def exit_initialization_mode(self) -> None:
        """Call :meth:`initialize` (the inputs set) and enter step mode; a StepFailure's reason is left in
        ``last_reason``.
        """
        self._require(INITIALIZATION, "exit_initialization_mode")
        self._run_hook(self.initialize, self.start_time)
        self.state = STEPPING

    def do_step(self, t: float, h: float) -> Status:
        """Advance one communication step; returns the status, the reason in ``last_reason``."""
        self._require(STEPPING, "do_step")
        return self._run_hook(lambda: self.step(t, h), t)

    def terminate(self) -> None:
        """Call :meth:`terminate_hook` and enter the terminated state; once only (again: nothing)."""
        if self.state != TERMINATED:
            self.terminate_hook()
            self.state = TERMINATED

    # -- get / set ---------------------------------------------------------------
    def get(self, name: str):
        """The current value of ``name`` (an array with the batch dimension first)."""
        self._variable(name)
        if name not in self.values:
            raise ComponentError(f"{self.name}.{name} has no value yet (no start value and never set)")
        return self.values[name]

    def set(self, name: str, value) -> None:
        """Set a parameter (before initialization ends) or an input; outputs cannot be set."""
        var = self._variable(name)
        if var.causality == "parameter":
            if self.state not in (INSTANTIATED, INITIALIZATION):
                raise ComponentError(f"{self.name}.{name} is a parameter and can only be set before "
                                     f"initialization ends (the component is in {self.state})")
        elif var.causality == "input":
            if self.state in (CREATED, TERMINATED):
                raise ComponentError(f"{self.name}.{name} cannot be set while the component is {self.state}")
        else:
            raise ComponentError(f"{self.name}.{name} is an {var.causality} and cannot be set")
        self.values[name] = self._coerce(var, value) if var.causality == "parameter" else self._check_shape(var, value)

    def model_description(self) -> str:
        """This component as a ``modelDescription.xml`` (FMI 2.0 co-simulation) string."""
        from .model_description import to_xml  # keeps XML out of the hot import path
        return to_xml(self)

    # -- helpers -------------------------------------------------------------------
    def _variable(self, name: str) -> Variable:
        try:
            return self.variables[name]
        except KeyError:
            raise ComponentError(f"{self.name} has no variable {name!r}; it has: "
                                 f"{', '.join(self.variables)}") from None

    def _require(self, state: str, action: str) -> None:
        if self.state != state:
            raise ComponentError(f"{self.name}: {action} needs the component {state}, but it is {self.state}")

    def _run_hook(self, hook, t: float) -> Status:
        try:
            hook()
        except StepFailure as failure:
            self.last_reason, self.failed_trials = failure.reason, failure.trials
            return failure.status
        self.last_reason, self.failed_trials = "", ()
        return Status.OK

    def _coerce(self, var: Variable, value):
        """Broadcast a start or parameter value to (B, *shape), checking type and range."""
        try:
            array = np.asarray(value)
            if var.type == "Boolean" and array.dtype != np.bool_:
                raise TypeError("not a boolean")
            if var.type == "Integer" and not np.issubdtype(array.dtype, np.integer):
                raise TypeError("not an integer")
            if not (np.issubdtype(array.dtype, np.number) or array.dtype == np.bool_):
                raise TypeError("not a number")
            array = np.broadcast_to(array.astype(var.dtype), (self.batch_size, *var.shape)).copy()
        except (TypeError, ValueError) as exc:
            raise ComponentError(f"{self.name}.{var.name}: {value!r} is not a {var.type} of per-trial "
                                 f"shape {var.shape} ({exc})") from None
        if var.min is not None and np.any(array < var.min) or var.max is not None and np.any(array > var.max):
            raise ComponentError(f"{self.name}.{var.name} = {value!r} is outside its range "
                                 f"[{var.min}, {var.max}] {var.unit}".rstrip())
        return array

    def _check_shape(self, var: Variable, value):
        """Inputs are passed by reference each step; only their shape is checked (cheap)."""
        expected = (self.batch_size, *var.shape)
        if tuple(getattr(value, "shape", ())) != expected:
            value = self._coerce(var, value)  # scalars and lists are broadcast once
        return value
