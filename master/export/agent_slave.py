"""The pythonfmu slave of the agent FMU: :class:`master.export.agent.Agent` behind the FMI 2.0 co-simulation API.

This file is the agent FMU's main script (``master/export/agent_fmu.py`` builds it). Unlike the body
FMU, it carries no copy of the code: it imports the ``rhi`` package (``master``, ``components``) of
the Python that loads it, which must have rhi and its dependencies (torch, ...) installed. Its
resources hold the decoder checkpoint and ``rhi_agent.json``: the decoder's kind, the configuration
it was built with and the ports it declared; a package whose agent declares other ports is refused
when the FMU is instantiated. One FMU instance is one trial (batch size 1). pythonfmu finds the class
by the literal line ``class ...(Fmi2Slave):``, so keep that line as it is.
"""
from __future__ import annotations

import traceback

import numpy as np
from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real
from pythonfmu.enums import Fmi2Status

FMI_TYPES = {"Real": Real, "Integer": Integer, "Boolean": Boolean}
PYTHON_TYPES = {"Real": float, "Integer": int, "Boolean": bool}


class AgentSlave(Fmi2Slave):
    """One trial of the rubber-hand agent, driven through FMI 2.0 co-simulation calls."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        try:
            from master.export.agent_fmu import agent_from_resources
        except ImportError as error:
            raise ImportError(f"the agent FMU needs a Python with the rhi package installed ({error})") from None
        self.agent, self.modelName, self.description = agent_from_resources(self.resources)
        self.author, self.license = "rhi", "MIT"
        self.agent.instantiate(1)
        self.scalars = list(self.agent.variables.values())
        for variable in self.scalars:
            self._register(variable)

    def _register(self, variable) -> None:
        name, cast = variable.name, PYTHON_TYPES[variable.type]
        agent, values = self.agent, self.agent.values
        if variable.causality == "parameter":
            variability = Fmi2Variability.fixed
            setter = lambda value: agent.set(name, np.array([cast(value)]))  # range-checked
        else:
            variability = Fmi2Variability.continuous if variable.type == "Real" else Fmi2Variability.discrete
            setter = (lambda value: values.__setitem__(name, np.array([cast(value)]))) \
                if variable.causality == "input" else None
        self.register_variable(FMI_TYPES[variable.type](
            name, causality=getattr(Fmi2Causality, variable.causality), variability=variability,
            description=variable.description, setter=setter,
            getter=lambda: cast(values[name][0]) if name in values else float("nan")))

    # -- FMI 2.0 lifecycle ------------------------------------------------------------------
    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        self.agent.setup_experiment(start_time, stop_time)

    def enter_initialization_mode(self):
        self.agent.enter_initialization_mode()

    def exit_initialization_mode(self):
        self.agent.exit_initialization_mode()
        if self.agent.last_reason:
            raise RuntimeError(self.agent.last_reason)

    def do_step(self, current_time, step_size):
        try:
            status = self.agent.do_step(current_time, step_size)
        except Exception as error:  # pythonfmu would only say "unknown error": log the cause, fail the step
            self.log("".join(traceback.format_exception_only(error)).strip(), Fmi2Status.error)
            return False
        if status >= 2:  # discard, error or fatal
            self.log(self.agent.last_reason or f"status {status}", Fmi2Status.error)
            return False
        return True

    def terminate(self):
        self.agent.terminate()

    # -- model description ----------------------------------------------------------------
    def to_xml(self, model_options=None):
        """pythonfmu's description, with the start values, units, ranges and output dependencies the
        agent declares, written by the functions that write a component's own model description."""
        from components.model_description import _format, model_structure, typed_attributes, unit_definitions
        root = super().to_xml(model_options or {})
        for element, variable in zip(root.iterfind("ModelVariables/ScalarVariable"), self.scalars):
            typed = element[0]
            if variable.causality in ("parameter", "input"):
                typed.set("start", _format(variable.start if variable.type != "Real" else float(variable.start)))
            for key, value in typed_attributes(variable).items():
                typed.set(key, value)
        definitions = unit_definitions(v.unit for v in self.scalars if v.type == "Real" and v.unit)
        if definitions is not None:
            root.insert(list(root).index(root.find("CoSimulation")) + 1, definitions)
        structure = root.find("ModelStructure")
        root[list(root).index(structure)] = model_structure(self.scalars)
        return root
