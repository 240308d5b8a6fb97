"""The pythonfmu slave: a native component (the arm plant) behind the FMI 2.0 co-simulation API.

This file is the FMU's main script. ``master/export/body.py`` bundles it with
a copy of the ``components`` package and a one-line resource file,
``rhi_component.txt``, that names the model and the component class to wrap
(``ArmBody components.body.plant:ArmPlant``): one slave class serves every body
variant. Each FMU instance is one trial (batch size 1); the slave base,
:class:`components.fmu_slave_base.ComponentSlaveBase`, taken from the FMU's own
copy of ``components``, registers the variables and runs the lifecycle. pythonfmu
takes the class of this file that has ``Fmi2Slave`` deepest among its bases.
"""
from __future__ import annotations

import importlib
import os
import sys

COMPONENT_FILE = "rhi_component.txt"  # "<model name> <module>:<class>", in the FMU's resources


_BUNDLES: dict[str, tuple[set, dict]] = {}  # resources folder -> (its packages, the modules imported from them)


def bundled(resources: str, spec: str):
    """``module:name`` from the FMU's own copy of its packages (a class, say).

    In a process that already imported this checkout's ``components`` (the master, under
    fmpy in-process), a plain import would return the host's modules. The packages in
    ``resources`` are imported with the host's modules of the same names set aside, and
    put back afterwards, so the FMU runs the code it carries and the host keeps its own.
    A folder is listed once: pythonfmu runs this file again from the module a process
    imported first, whose folder (a builder's staging folder) may be gone by then.
    """
    if resources not in _BUNDLES:
        own = {entry.removesuffix(".py") for entry in os.listdir(resources)
               if entry.endswith(".py") or os.path.isfile(os.path.join(resources, entry, "__init__.py"))}
        _BUNDLES[resources] = own - {__name__, "pythonfmu"}, {}
    own, bundle = _BUNDLES[resources]
    ours = lambda module: module.partition(".")[0] in own
    host = {name: module for name, module in sys.modules.items() if ours(name)}
    for name in host:
        del sys.modules[name]
    sys.modules.update(bundle)
    sys.path.insert(0, resources)
    try:
        module, _, name = spec.partition(":")
        return getattr(importlib.import_module(module), name)
    finally:
        sys.path.remove(resources)
        bundle.update({name: module for name, module in sys.modules.items() if ours(name)})
        for name in bundle:
            sys.modules.pop(name, None)
        sys.modules.update(host)


# The base from the copy this file sits beside (the FMU's resources, or the builder's staging folder).
ComponentSlaveBase = bundled(os.path.dirname(os.path.abspath(__file__)),
                             "components.fmu_slave_base:ComponentSlaveBase")
xml_value = bundled(os.path.dirname(os.path.abspath(__file__)), "components.model_description:xml_value")


class ComponentSlave(ComponentSlaveBase):
    """One trial of a native component, driven through FMI 2.0 co-simulation calls."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        with open(os.path.join(self.resources, COMPONENT_FILE)) as file:
            self.modelName, spec = file.read().split()
        component = bundled(self.resources, spec)()
        doc = (type(component).__doc__ or "").strip()
        self.description = doc.splitlines()[0] if doc else spec
        self.serve(component)

    def start_text(self, variable, written):
        """A Real's start as the instantiated component holds it, to 17 digits (pythonfmu writes fewer; an
        infinite one as XML Schema writes it, INF)."""
        if variable.type == "Real" and written is not None:
            return xml_value(float(self.component.values[variable.name][0]))
        return written
