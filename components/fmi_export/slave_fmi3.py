"""The pythonfmu3 slave base: one trial of a component (the fixed-step protocol of :mod:`rhi.components.component`)
behind the FMI 3.0 co-simulation API, its ports grouped into Float64 arrays as its FMI 3.0 description says.

The FMI 3.0 twin of :mod:`rhi.components.fmi_export.slave_fmi2`: the body FMU's FMI 3.0 slave
(``components/body/fmu_slave3.py``) makes its component and hands it to :meth:`ComponentSlave3Base.serve` with
the arrays (:data:`rhi.components.body.contract.FMI3_ARRAYS`). The model description is
:func:`rhi.components.fmi_export.description_fmi3.to_xml3`'s, the one the C body's FMI 3.0 build carries, so the value
references are the FMI 2.0 ones (an array's is its first element's; ``time`` follows the last) and pythonfmu3's
own numbering (registration order) is replaced by them. The body FMU carries a copy of this module in its copy of
``components``.
"""
from __future__ import annotations

from xml.etree import ElementTree as ET

import numpy as np
from pythonfmu3 import Boolean, Dimension, Fmi3Causality, Fmi3Slave, Fmi3Variability, Float64, Int32
from pythonfmu3.enums import Fmi3Status

from .calls import exit_initialization, step
from .description_fmi3 import layout, to_xml3

FMI_TYPES = {"Real": Float64, "Integer": Int32, "Boolean": Boolean}
PYTHON_TYPES = {"Real": float, "Integer": int, "Boolean": bool}


class Fmi3Lifecycle:
    """The FMI 3.0 co-simulation calls on ``self.component`` (one trial of a component of
    :mod:`rhi.components.component`), for a pythonfmu3 slave: the body's (:class:`ComponentSlave3Base`) and the agent's
    (``rhi.master.export.agent_fmi3``). ``time`` follows the steps."""

    def setup_experiment(self, start_time):
        """The start time fmi3EnterInitializationMode gives, s (pythonfmu3 does not pass the stop time on)."""
        self.component.setup_experiment(start_time, None)
        self.time = start_time

    def enter_initialization_mode(self):
        """fmi3EnterInitializationMode: the component enters initialization mode."""
        self.component.enter_initialization_mode()

    def exit_initialization_mode(self):
        """fmi3ExitInitializationMode: the component initializes; a failure is logged as one line and raised."""
        exit_initialization(self.component, self.log, Fmi3Status.error)

    def do_step(self, current_time, step_size):
        """fmi3DoStep: one step of the component; False (discard) when it failed, its reason logged. ``time`` is
        then the step's end, ``current_time + step_size`` (as the C body sums it)."""
        if not step(self.component, current_time, step_size, self.log, Fmi3Status.error):
            return False
        self.time = current_time + step_size
        return True

    def terminate(self):
        """fmi3Terminate: the component terminates."""
        self.component.terminate()


class ComponentSlave3Base(Fmi3Lifecycle, Fmi3Slave):
    """One trial (batch size 1) of ``self.component``, driven through FMI 3.0 co-simulation calls."""

    def serve(self, component, arrays: dict) -> None:
        """Instantiate ``component`` for one trial and register its FMI 3.0 variables (``arrays`` as in
        :func:`rhi.components.fmi_export.description_fmi3.layout`) at their value references, then ``time``."""
        self.component, self.arrays = component, arrays
        component.instantiate(1)
        for name, reference, group, description in layout(component, arrays):
            self._register(name, reference, group, description)
        self.time = 0.0
        self._place(Float64("time", causality=Fmi3Causality.independent, variability=Fmi3Variability.continuous,
                            getter=lambda: self.time), len(component.variables))

    def _place(self, variable, reference: int) -> None:
        """``variable`` at ``reference`` (pythonfmu3's register_variable would number it by registration order)."""
        variable.value_reference = reference
        self.vars[reference] = variable

    def _register(self, name: str, reference: int, group: tuple, description: str) -> None:
        """The FMI 3.0 variable ``name`` carrying the declared variables ``group`` (an array if more than one)."""
        first, members = group[0], [v.name for v in group]
        cast, component, values = PYTHON_TYPES[first.type], self.component, self.component.values
        read = lambda member: cast(values[member][0]) if member in values else float("nan")  # as the FMI 2.0 slave
        pairs = (lambda value: zip(members, value)) if len(group) > 1 else (lambda value: ((name, value),))

        def set_parameter(value):
            for member, element in pairs(value):
                component.set(member, np.array([cast(element)]))  # range-checked

        def set_input(value):  # the fast path: no check, as the FMI 2.0 slave's
            for member, element in pairs(value):
                values[member] = np.array([cast(element)])

        setter = {"parameter": set_parameter, "input": set_input}.get(first.causality)
        getter = (lambda: [read(member) for member in members]) if len(group) > 1 else (lambda: read(name))
        variability = Fmi3Variability.fixed if first.causality == "parameter" else \
            Fmi3Variability.continuous if first.type == "Real" else Fmi3Variability.discrete
        dimensions = [Dimension(start=str(len(group)))] if len(group) > 1 else []
        self._place(FMI_TYPES[first.type](name, causality=getattr(Fmi3Causality, first.causality),
                                          variability=variability, description=description, getter=getter,
                                          setter=setter, dimensions=dimensions), reference)

    def set_float64(self, vrs, values):
        """fmi3SetFloat64: refused unless ``values`` holds exactly the variables' elements (pythonfmu3 takes what an
        array's size says and ignores the rest), so that half an array, or one array's values spilling into the next,
        is never taken. pythonfmu3 reports the refusal, as any exception here, as fmi3Fatal."""
        expected = sum(self.vars[vr].size(self.vars) if vr in self.vars else 1 for vr in vrs)
        if len(values) != expected:
            raise ValueError(f"fmi3SetFloat64: {len(values)} values for {expected} elements")
        super().set_float64(vrs, values)

    # -- model description ----------------------------------------------------------------
    def to_xml(self, model_options=None):
        """The component's FMI 3.0 description (:func:`~rhi.components.fmi_export.description_fmi3.to_xml3`, the C body's
        writer) with pythonfmu3's ``CoSimulation`` (its model identifier, the library's name, and
        ``needsExecutionTool``: a Python) and log categories, the model name pythonfmu3 names the FMU by and its
        generation tool."""
        root = ET.fromstring(to_xml3(self.component, self.arrays))
        for element in root.iter():  # to_xml3's indentation: pythonfmu3's builder indents again
            element.text = element.text if element.text and element.text.strip() else None
            element.tail = None
        ours = super().to_xml(model_options or {})
        root.set("modelName", self.modelName)
        root.set("generationTool", ours.get("generationTool"))  # the binary and the calls are pythonfmu3's
        cosimulation = ours.find("CoSimulation")
        cosimulation.set("canHandleVariableCommunicationStepSize", "true")  # as the FMI 2.0 body
        at = list(root).index(root.find("CoSimulation"))
        root[at] = cosimulation
        root.insert(at + 2, ours.find("LogCategories"))  # after UnitDefinitions, as the schema orders them
        return root
