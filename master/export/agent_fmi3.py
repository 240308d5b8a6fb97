"""The agent behind the FMI 3.0 co-simulation API (pythonfmu3): :class:`AgentSlave3`, which the agent FMU's FMI 3.0
slave script (``master/export/agent_slave3.py``) serves.

The same agent and ports as the FMI 2.0 FMU (``master/export/agent_slave.py``), as FMI 3.0 types (a Real a
``Float64``, an Integer an ``Int32``), plus:

- ``image``: the camera's image, the decoder's input, a ``Float64`` array output of the camera's resolution
  (rows, columns), row by row (a master reads or replaces the whole image, and a checker sees its shape);
- the touches as discrete outputs: ``visual_time`` and ``tactile_time``, which change only at a visual or a felt
  event, are declared ``discrete`` (pythonfmu3 has no clocks, and no event mode);
- ``time``, FMI 3.0's independent variable, after the agent's ports.

Value references follow the FMI 2.0 ones (the agent's declaration order); ``image`` and ``time`` come after.
"""
from __future__ import annotations

from xml.etree import ElementTree as ET

import numpy as np
from pythonfmu3 import Boolean, Dimension, Fmi3Causality, Fmi3Slave, Fmi3Variability, Float64, Int32

from rhi.components.fmi_export.slave_fmi3 import Fmi3Lifecycle
from rhi.components.model_description import typed_attributes, unit_definitions, xml_value
from rhi.master.export.agent_fmu import agent_from_resources

TYPES = {"Real": Float64, "Integer": Int32, "Boolean": Boolean}
CASTS = {"Real": float, "Integer": int, "Boolean": bool}
TOUCHES = ("visual_time", "tactile_time")  # outputs that change only at an event: discrete
IMAGE, IMAGE_PATH = "image", "camera.image"


def variability(variable) -> Fmi3Variability:
    """A port's FMI 3.0 variability: a parameter's ``fixed``; an event time's, an Integer's or a Boolean's
    ``discrete``; a Real's ``continuous``."""
    if variable.causality == "parameter":
        return Fmi3Variability.fixed
    if variable.type != "Real" or variable.name in TOUCHES:
        return Fmi3Variability.discrete
    return Fmi3Variability.continuous


class AgentSlave3(Fmi3Lifecycle, Fmi3Slave):
    """One trial of the agent (the illusion's or the reach's) through FMI 3.0 co-simulation calls."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.component, self.modelName, self.description = agent_from_resources(self.resources)
        self.author, self.license = "rhi", "MIT"
        self.component.instantiate(1)
        self.scalars = [v for v in self.component.variables.values() if v.type != "Array"]
        values = self.component.values
        for variable in self.scalars:
            name, cast = variable.name, CASTS[variable.type]
            if variable.causality == "parameter":
                setter = lambda value, name=name, cast=cast: self.component.set(name, np.array([cast(value)]))
            elif variable.causality == "input":
                setter = lambda value, name=name, cast=cast: values.__setitem__(name, np.array([cast(value)]))
            else:
                setter = None
            self.register_variable(TYPES[variable.type](
                name, causality=getattr(Fmi3Causality, variable.causality), variability=variability(variable),
                description=variable.description, setter=setter,
                getter=lambda name=name, cast=cast: cast(values[name][0]) if name in values else float("nan")))
        self.shape = tuple(int(n) for n in self.component.inner_variable(IMAGE_PATH).shape)
        self.register_variable(Float64(
            IMAGE, causality=Fmi3Causality.output, variability=Fmi3Variability.continuous,
            dimensions=[Dimension(start=str(n)) for n in self.shape], getter=self.image,
            description="the camera's image (the decoder's input), rows by columns, row by row"))
        self.time = 0.0
        self.register_variable(Float64("time", causality=Fmi3Causality.independent,
                                       variability=Fmi3Variability.continuous))

    def image(self) -> list:
        """The camera's image now, row by row (NaN before initialization)."""
        image = self.component.inner(IMAGE_PATH)
        if image is None:
            return [float("nan")] * int(np.prod(self.shape))
        return np.asarray(image[0], dtype=np.float64).ravel().tolist()

    # -- model description -----------------------------------------------------------------
    def to_xml(self, model_options=None):
        """pythonfmu3's description plus what it leaves out, as the FMI 2.0 agent's: units, ranges, the starts as
        the agent declares them, ``initial``, and a model structure whose outputs depend on no input."""
        root = super().to_xml(model_options or {})
        root.find("CoSimulation").set("canHandleVariableCommunicationStepSize", "true")  # as the FMI 2.0 agent
        elements = {e.get("name"): e for e in root.find("ModelVariables")}
        for variable in self.scalars:
            element = elements[variable.name]
            if variable.causality in ("parameter", "input"):
                element.set("start", xml_value(variable.start if variable.type != "Real" else float(variable.start)))
            if variable.causality == "output":
                element.set("initial", "calculated")
                element.attrib.pop("start", None)
            elif variable.causality == "parameter":
                element.set("initial", "exact")
            for key, value in typed_attributes(variable).items():
                element.set(key, value)
        elements[IMAGE].set("initial", "calculated")
        elements[IMAGE].set("unit", "1")
        elements["time"].set("unit", "s")
        definitions = unit_definitions([v.unit for v in self.scalars if v.type == "Real" and v.unit] + ["1", "s"])
        root.insert(list(root).index(root.find("CoSimulation")) + 1, definitions)
        structure = root.find("ModelStructure")
        for unknown in structure:  # every output is state: it depends on no input within a step
            unknown.set("dependencies", "")
        return root
