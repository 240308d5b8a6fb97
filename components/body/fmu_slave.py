"""The pythonfmu slave: a native component (the arm plant) behind the FMI 2.0 co-simulation API.

This file is the FMU's main script. ``master/export/body.py`` bundles it with
a copy of the ``components`` package and a one-line resource file,
``rhi_component.txt``, that names the model and the component class to wrap
(``ArmBody components.body.plant:ArmPlant``): one slave class serves every body
variant. Each FMU instance is one trial (batch size 1); every scalar variable of
the component becomes an FMI variable with its unit, range and description, and
value references follow the declaration order. pythonfmu finds the class by the
literal line ``class ...(Fmi2Slave):``, so keep that line as it is.
"""
from __future__ import annotations

import importlib
import os
import sys
import traceback

import numpy as np
from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real
from pythonfmu.enums import Fmi2Status

COMPONENT_FILE = "rhi_component.txt"  # "<model name> <module>:<class>", in the FMU's resources
FMI_TYPES = {"Real": Real, "Integer": Integer, "Boolean": Boolean}
PYTHON_TYPES = {"Real": float, "Integer": int, "Boolean": bool}


_BUNDLES: dict[str, dict] = {}  # resources folder -> the modules imported from it


def load_component(resources: str, spec: str):
    """``module:Class`` from the FMU's own copy of its packages -> a new instance (default name).

    In a process that already imported this checkout's ``components`` (the master, under
    fmpy in-process), a plain import would return the host's modules. The packages in
    ``resources`` are imported with the host's modules of the same names set aside, and
    put back afterwards, so the FMU runs the code it carries and the host keeps its own.
    """
    own = {entry.removesuffix(".py") for entry in os.listdir(resources)
           if entry.endswith(".py") or os.path.isfile(os.path.join(resources, entry, "__init__.py"))}
    own -= {__name__, "pythonfmu"}
    ours = lambda module: module.partition(".")[0] in own
    host = {name: module for name, module in sys.modules.items() if ours(name)}
    bundle = _BUNDLES.setdefault(resources, {})
    for name in host:
        del sys.modules[name]
    sys.modules.update(bundle)
    sys.path.insert(0, resources)
    try:
        module, _, name = spec.partition(":")
        return getattr(importlib.import_module(module), name)()
    finally:
        sys.path.remove(resources)
        bundle.update({name: module for name, module in sys.modules.items() if ours(name)})
        for name in bundle:
            sys.modules.pop(name, None)
        sys.modules.update(host)


class ComponentSlave(Fmi2Slave):
    """One trial of a native component, driven through FMI 2.0 co-simulation calls."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        with open(os.path.join(self.resources, COMPONENT_FILE)) as file:
            self.modelName, spec = file.read().split()
        self.component = load_component(self.resources, spec)
        doc = (type(self.component).__doc__ or "").strip()
        self.description = doc.splitlines()[0] if doc else spec
        self.component.instantiate(1)
        self.scalars = [v for v in self.component.variables.values() if v.type != "Array"]
        for variable in self.scalars:
            self._register(variable)

    def _register(self, variable) -> None:
        name, cast = variable.name, PYTHON_TYPES[variable.type]
        values = self.component.values
        causality = getattr(Fmi2Causality, variable.causality)
        if variable.causality == "parameter":
            variability = Fmi2Variability.fixed
        else:
            variability = Fmi2Variability.continuous if variable.type == "Real" else Fmi2Variability.discrete
        if variable.causality == "parameter":
            setter = lambda value: self.component.set(name, np.array([cast(value)]))  # range-checked
        elif variable.causality == "input":
            setter = lambda value: values.__setitem__(name, np.array([cast(value)]))  # the fast path
        else:
            setter = None
        self.register_variable(FMI_TYPES[variable.type](
            name, causality=causality, variability=variability, description=variable.description,
            getter=lambda: cast(values[name][0]) if name in values else float("nan"), setter=setter))

    # -- FMI 2.0 lifecycle ------------------------------------------------------------------
    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        self.component.setup_experiment(start_time, stop_time)

    def enter_initialization_mode(self):
        self.component.enter_initialization_mode()

    def exit_initialization_mode(self):
        self.component.exit_initialization_mode()
        if self.component.last_reason:
            raise RuntimeError(self.component.last_reason)

    def do_step(self, current_time, step_size):
        try:
            status = self.component.do_step(current_time, step_size)
        except Exception as error:  # pythonfmu would only say "unknown error": log the cause, fail the step
            self.log("".join(traceback.format_exception_only(error)).strip(), Fmi2Status.error)
            return False
        if status >= 2:  # discard, error or fatal
            self.log(self.component.last_reason or f"status {status}", Fmi2Status.error)
            return False
        return True

    def terminate(self):
        self.component.terminate()

    # -- model description ----------------------------------------------------------------
    def to_xml(self, model_options=None):
        """pythonfmu's description plus what it leaves out: units, ranges, exact start values,
        output dependencies and initial unknowns (so masters see the outputs are state), written
        by the functions that write a component's own model description."""
        from components.model_description import model_structure, typed_attributes, unit_definitions
        root = super().to_xml(model_options or {})
        for element, variable in zip(root.iterfind("ModelVariables/ScalarVariable"), self.scalars):
            typed = element[0]
            if variable.type == "Real" and typed.get("start") is not None:
                typed.set("start", repr(float(self.component.values[variable.name][0])))  # 17 digits
            for key, value in typed_attributes(variable).items():
                typed.set(key, value)
        definitions = unit_definitions(v.unit for v in self.scalars if v.type == "Real" and v.unit)
        if definitions is not None:
            root.insert(list(root).index(root.find("CoSimulation")) + 1, definitions)
        structure = root.find("ModelStructure")
        root[list(root).index(structure)] = model_structure(self.scalars)
        return root
