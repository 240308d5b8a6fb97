"""The pythonfmu3 slave: a native component (the arm plant) behind the FMI 3.0 co-simulation API.

This file is the FMI 3.0 body FMU's main script, the twin of ``components/body/fmu_slave.py`` (FMI 2.0):
``master/export/body.py`` bundles it with a copy of the ``components`` package and the same one-line
``rhi_component.txt`` (``ArmBody components.body.plant:ArmPlant``). The slave base,
:class:`rhi.components.fmu_slave3_base.ComponentSlave3Base`, and the arrays,
:data:`rhi.components.body.contract.FMI3_ARRAYS`, are taken from the FMU's own copy of ``components``. pythonfmu3
(its builder and its library both) takes the class of this file that names ``Fmi3Slave`` among its bases.
"""
from __future__ import annotations

import importlib.util
import os
import sys

from pythonfmu3 import Fmi3Slave

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
ComponentSlave3Base = bundled(HERE, "components.fmu_slave3_base:ComponentSlave3Base")


class ComponentSlave(ComponentSlave3Base, Fmi3Slave):
    """One trial of a native component, driven through FMI 3.0 co-simulation calls."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.modelName, component, self.description = _BUNDLE.served_component(self.resources, __name__)
        self.serve(component, bundled(self.resources, "components.body.contract:FMI3_ARRAYS"))
