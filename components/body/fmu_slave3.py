"""The pythonfmu3 slave: a native component (the arm plant) behind the FMI 3.0 co-simulation API.

This file is the FMI 3.0 body FMU's main script, the twin of ``components/body/fmu_slave.py`` (FMI 2.0):
``master/export/body.py`` bundles it with a copy of the ``components`` package and the same one-line
``rhi_component.txt`` (``ArmBody components.body.plant:ArmPlant``). The slave base,
:class:`rhi.components.fmi_export.slave_fmi3.ComponentSlave3Base`, and the arrays,
:data:`rhi.components.body.contract.FMI3_ARRAYS`, are taken from the FMU's own copy of ``components``. pythonfmu3
(its builder and its library both) takes the class of this file that names ``Fmi3Slave`` among its bases.
"""
from __future__ import annotations

import os
import runpy

from pythonfmu3 import Fmi3Slave

HERE = os.path.dirname(os.path.abspath(__file__))  # the FMU's resources, or the builder's staging folder
# The bootstrap both body slave scripts share, from the copy beside this file (run by its path: the host's
# ``components`` would answer to its name); the module's own when this file runs again in it (pythonfmu's builder
# reloads it, its library runs it again), as the folder it came from may be gone by then.
BUNDLE = globals().get("BUNDLE") or runpy.run_path(
    os.path.join(HERE, "components", "fmi_export", "bundle.py"))["for_script"](__name__)
ComponentSlave3Base = BUNDLE.bundled(HERE, "components.fmi_export.slave_fmi3:ComponentSlave3Base", __name__)


class ComponentSlave(ComponentSlave3Base, Fmi3Slave):
    """One trial of a native component, driven through FMI 3.0 co-simulation calls."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.modelName, component, self.description = BUNDLE.served_component(self.resources, __name__)
        self.serve(component, BUNDLE.bundled(self.resources, "components.body.contract:FMI3_ARRAYS", __name__))
