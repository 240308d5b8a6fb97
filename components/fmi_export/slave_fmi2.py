"""The pythonfmu slave base: one trial of a component (the fixed-step protocol of
:mod:`rhi.components.component`) behind the FMI 2.0 co-simulation API.

The body FMU's slave (``components/body/fmu_slave.py``) and the agent FMU's
(``master/export/agent_slave.py``) extend :class:`ComponentSlaveBase`: each makes
its component and hands it to :meth:`~ComponentSlaveBase.serve`. Every scalar
variable becomes an FMI variable with its unit, range and description, value
references follow the declaration order, and the description pythonfmu writes
gets what it leaves out. The body FMU carries a copy of this module in its copy
of ``components``.
"""
from __future__ import annotations


import numpy as np
from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real
from pythonfmu.enums import Fmi2Status

from .calls import exit_initialization, step
from ..model_description import model_structure, typed_attributes, unit_definitions

FMI_TYPES = {"Real": Real, "Integer": Integer, "Boolean": Boolean}
PYTHON_TYPES = {"Real": float, "Integer": int, "Boolean": bool}


class ComponentSlaveBase(Fmi2Slave):
    """One trial (batch size 1) of ``self.component``, driven through FMI 2.0 co-simulation calls."""

    def serve(self, component) -> None:
        """Instantiate ``component`` for one trial and register its scalar variables, in declaration order."""
        self.component = component
        component.instantiate(1)
        self.scalars = [v for v in component.variables.values() if v.type != "Array"]
        for variable in self.scalars:
            self._register(variable)

    def _register(self, variable) -> None:
        name, cast = variable.name, PYTHON_TYPES[variable.type]
        component, values = self.component, self.component.values
        if variable.causality == "parameter":
            variability = Fmi2Variability.fixed
            setter = lambda value: component.set(name, np.array([cast(value)]))  # range-checked
        else:
            variability = Fmi2Variability.continuous if variable.type == "Real" else Fmi2Variability.discrete
            setter = (lambda value: values.__setitem__(name, np.array([cast(value)]))) \
                if variable.causality == "input" else None  # an input's setter is the fast path
        self.register_variable(FMI_TYPES[variable.type](
            name, causality=getattr(Fmi2Causality, variable.causality), variability=variability,
            description=variable.description, setter=setter,
            getter=lambda: cast(values[name][0]) if name in values else float("nan")))

    # -- FMI 2.0 lifecycle ------------------------------------------------------------------
    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        """fmi2SetupExperiment: the component's start and stop times, s (``tolerance`` is not used)."""
        self.component.setup_experiment(start_time, stop_time)

    def enter_initialization_mode(self):
        """fmi2EnterInitializationMode: the component enters initialization mode."""
        self.component.enter_initialization_mode()

    def exit_initialization_mode(self):
        """fmi2ExitInitializationMode: the component initializes; a failure is logged as one line and raised."""
        exit_initialization(self.component, self.log, Fmi2Status.error)

    def do_step(self, current_time, step_size):
        """fmi2DoStep: one step of the component.

        Parameters
        ----------
        current_time, step_size : float
            The step's start and size, s.

        Returns
        -------
        bool
            False when the step failed (an exception, or a status of discard or worse), its reason logged.
        """
        return step(self.component, current_time, step_size, self.log, Fmi2Status.error)

    def terminate(self):
        """fmi2Terminate: the component terminates."""
        self.component.terminate()

    # -- model description ----------------------------------------------------------------
    def start_text(self, variable, written: str | None) -> str | None:
        """The start attribute ``variable`` gets in the description; ``written``: pythonfmu's (None: none).

        Default: pythonfmu's. A subclass says which start values it writes itself, and how.
        """
        return written

    def to_xml(self, model_options=None):
        """pythonfmu's description plus what it leaves out: units, ranges, start values (:meth:`start_text`),
        ``initial`` (FMI 2.0's defaults said out, as a component's own description says them: ``calculated`` on an
        output, which has no start, ``exact`` on a parameter), output dependencies and initial unknowns (so
        masters see the outputs are state), written by the functions that write a component's own model
        description."""
        root = super().to_xml(model_options or {})
        for element, variable in zip(root.iterfind("ModelVariables/ScalarVariable"), self.scalars):
            typed = element[0]
            start = self.start_text(variable, typed.get("start"))
            if start is not None:
                typed.set("start", start)
            if variable.causality in ("output", "local"):
                element.set("initial", "calculated")
                typed.attrib.pop("start", None)
            elif variable.causality == "parameter" and typed.get("start") is not None:
                element.set("initial", "exact")
            for key, value in typed_attributes(variable).items():
                typed.set(key, value)
        definitions = unit_definitions(v.unit for v in self.scalars if v.type == "Real" and v.unit)
        if definitions is not None:
            root.insert(list(root).index(root.find("CoSimulation")) + 1, definitions)
        structure = root.find("ModelStructure")
        root[list(root).index(structure)] = model_structure(self.scalars)
        return root
