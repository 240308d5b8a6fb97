"""The pythonfmu slave: a native component (the arm plant) behind the FMI 2.0 co-simulation API.

This file is the FMU's main script. ``master/export/body.py`` bundles it with
a copy of the ``components`` package and a one-line resource file,
``rhi_component.txt``, that names the model and the component class to wrap
(``ArmBody components.body.plant:ArmPlant``): one slave class serves every body
variant. Each FMU instance is one trial (batch size 1); the slave base,
:class:`rhi.components.fmi_export.slave_fmi2.ComponentSlaveBase`, taken from the FMU's own
copy of ``components``, registers the variables and runs the lifecycle. pythonfmu
takes the class of this file that has ``Fmi2Slave`` deepest among its bases.
"""
from __future__ import annotations

import os
import runpy

HERE = os.path.dirname(os.path.abspath(__file__))  # the FMU's resources, or the builder's staging folder
# The bootstrap both body slave scripts share, from the copy beside this file (run by its path: the host's
# ``components`` would answer to its name); the module's own when this file runs again in it (pythonfmu's builder
# reloads it, its library runs it again), as the folder it came from may be gone by then.
BUNDLE = globals().get("BUNDLE") or runpy.run_path(
    os.path.join(HERE, "components", "fmi_export", "bundle.py"))["for_script"](__name__)
ComponentSlaveBase = BUNDLE.bundled(HERE, "components.fmi_export.slave_fmi2:ComponentSlaveBase", __name__)
xml_value = BUNDLE.bundled(HERE, "components.model_description:xml_value", __name__)


class ComponentSlave(ComponentSlaveBase):
    """One trial of a native component, driven through FMI 2.0 co-simulation calls."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.modelName, component, self.description = BUNDLE.served_component(self.resources, __name__)
        self.serve(component)

    def start_text(self, variable, written):
        """A Real's start as the instantiated component holds it, to 17 digits (pythonfmu writes fewer; an
        infinite one as XML Schema writes it, INF)."""
        if variable.type == "Real" and written is not None:
            return xml_value(float(self.component.values[variable.name][0]))
        return written
