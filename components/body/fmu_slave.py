"""The pythonfmu slave: a native component (the arm plant) behind the FMI 2.0 co-simulation API.

This file is the FMU's main script. ``master/export/body.py`` bundles it with
a copy of the ``components`` package and a one-line resource file,
``rhi_component.txt``, that names the model and the component class to wrap
(``ArmBody components.body.plant:ArmPlant``): one slave class serves every body
variant. Each FMU instance is one trial (batch size 1); the slave base,
:class:`rhi.components.fmu_slave_base.ComponentSlaveBase`, taken from the FMU's own
copy of ``components``, registers the variables and runs the lifecycle. pythonfmu
takes the class of this file that has ``Fmi2Slave`` deepest among its bases.
"""
from __future__ import annotations

import importlib.util
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))  # the FMU's resources, or the builder's staging folder


def own_bundle():
    """``components/fmu_bundle.py`` of the copy beside this file, loaded by its path (not imported by name: the
    host's ``components`` would answer), once per process under a name of this script's: pythonfmu's library runs
    this file again from the module a process imported first, whose folder (a builder's staging folder) may be
    gone by then."""
    name = f"{__name__}_bundle"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, os.path.join(HERE, "components", "fmu_bundle.py"))
        sys.modules[name] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(sys.modules[name])
    return sys.modules[name]


def bundled(resources: str, spec: str):
    """``module:name`` from the FMU's own copy of its packages (:func:`rhi.components.fmu_bundle.bundled`)."""
    return _BUNDLE.bundled(resources, spec, __name__)


_BUNDLE = own_bundle()
# The base from the copy this file sits beside.
ComponentSlaveBase = bundled(HERE, "components.fmu_slave_base:ComponentSlaveBase")
xml_value = bundled(HERE, "components.model_description:xml_value")


class ComponentSlave(ComponentSlaveBase):
    """One trial of a native component, driven through FMI 2.0 co-simulation calls."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.modelName, component, self.description = _BUNDLE.served_component(self.resources, __name__)
        self.serve(component)

    def start_text(self, variable, written):
        """A Real's start as the instantiated component holds it, to 17 digits (pythonfmu writes fewer; an
        infinite one as XML Schema writes it, INF)."""
        if variable.type == "Real" and written is not None:
            return xml_value(float(self.component.values[variable.name][0]))
        return written
