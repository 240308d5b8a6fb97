"""The model-description view: a component as an FMI 2.0 ``modelDescription.xml``.

Scalar variables become ``ScalarVariable`` elements with value references in
declaration order; ``Array`` ports, which FMI 2.0 cannot carry, are listed under
``VendorAnnotations/Tool[@name='rhi']/Arrays``. Output dependencies go into
``ModelStructure`` as FMI defines them. fmpy's ``read_model_description``
validates the result against the FMI 2.0 schema (see the tests).
"""
from __future__ import annotations

import math
import uuid
from xml.etree import ElementTree as ET

# SI base-unit exponents and factor for the units this project uses.
BASE_UNITS = {
    "m": ({"m": 1}, 1.0),
    "s": ({"s": 1}, 1.0),
    "N": ({"kg": 1, "m": 1, "s": -2}, 1.0),
    "deg": ({"rad": 1}, math.pi / 180),
    "deg/s": ({"rad": 1, "s": -1}, math.pi / 180),
    "1/s": ({"s": -1}, 1.0),
    "kg": ({"kg": 1}, 1.0),
    "N/m": ({"kg": 1, "s": -2}, 1.0),
    "N.m": ({"kg": 1, "m": 2, "s": -2}, 1.0),
    "N.s/m": ({"kg": 1, "s": -1}, 1.0),
    "N.m.s/rad": ({"kg": 1, "m": 2, "s": -1, "rad": -1}, 1.0),
    "deg/s2": ({"rad": 1, "s": -2}, math.pi / 180),
    "1": ({}, 1.0),
}

VARIABILITY = {"parameter": "fixed", "input": "continuous", "output": "continuous", "local": "continuous"}


def xml_value(value) -> str:
    """A start value as XML Schema writes it (true/false, INF, -INF, NaN)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isnan(value):
            return "NaN"
        return {math.inf: "INF", -math.inf: "-INF"}.get(value, repr(value))
    return str(value)


def unit_definitions(units) -> ET.Element | None:
    """``UnitDefinitions`` for ``units`` (sorted, each once) with their SI base units; None if there are none.

    A unit missing from BASE_UNITS is declared by name only.
    """
    units = sorted(set(units))
    if not units:
        return None
    definitions = ET.Element("UnitDefinitions")
    for unit in units:
        element = ET.SubElement(definitions, "Unit", {"name": unit})
        if unit in BASE_UNITS:
            exponents, factor = BASE_UNITS[unit]
            attributes = {k: str(e) for k, e in exponents.items()}
            if factor != 1.0:
                attributes["factor"] = repr(factor)
            ET.SubElement(element, "BaseUnit", attributes)
    return definitions


def typed_attributes(variable) -> dict:
    """The unit (of a Real) and the range (of a Real or an Integer) on a scalar's typed element."""
    attributes = {"unit": variable.unit} if variable.type == "Real" and variable.unit else {}
    cast = {"Real": float, "Integer": int}.get(variable.type)
    for bound in ("min", "max"):
        if getattr(variable, bound) is not None and cast is not None:
            attributes[bound] = xml_value(cast(getattr(variable, bound)))
    return attributes


def model_structure(scalars) -> ET.Element:
    """``ModelStructure``: each scalar output with the scalar inputs it depends on directly, and as an
    initial unknown. ``scalars``: the scalar variables in value-reference order (index = position + 1)."""
    structure = ET.Element("ModelStructure")
    index = {v.name: i + 1 for i, v in enumerate(scalars)}  # FMI indices are 1-based
    outputs = [v for v in scalars if v.causality == "output"]
    inputs = [v.name for v in scalars if v.causality == "input"]
    if outputs:
        section = ET.SubElement(structure, "Outputs")
        for v in outputs:
            # None means every input; only scalar inputs have an index to name.
            sources = inputs if v.depends_on is None else v.depends_on
            ET.SubElement(section, "Unknown", {
                "index": str(index[v.name]), "dependencies": " ".join(str(index[n]) for n in sources if n in index)})
        initial = ET.SubElement(structure, "InitialUnknowns")
        for v in outputs:
            ET.SubElement(initial, "Unknown", {"index": str(index[v.name])})
    return structure


def to_xml(component) -> str:
    """Return the FMI 2.0 co-simulation model description of ``component``."""
    variables = list(component.variables.values())
    scalars = [v for v in variables if v.type != "Array"]
    arrays = [v for v in variables if v.type == "Array"]

    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0",
        "modelName": type(component).__name__,
        "guid": "{%s}" % uuid.uuid5(uuid.NAMESPACE_URL, repr([(v.name, v.causality, v.type, v.shape, v.unit)
                                                                for v in variables])),
        "description": (type(component).__doc__ or "").strip().splitlines()[0] if type(component).__doc__ else "",
        "generationTool": "rhi",
        "variableNamingConvention": "flat",
        "numberOfEventIndicators": "0",
    })
    ET.SubElement(root, "CoSimulation", {"modelIdentifier": component.name,
                                         "canHandleVariableCommunicationStepSize": "true"})
    definitions = unit_definitions(v.unit for v in variables if v.unit)
    if definitions is not None:
        root.append(definitions)
    if arrays:
        tool = ET.SubElement(ET.SubElement(root, "VendorAnnotations"), "Tool", {"name": "rhi"})
        holder = ET.SubElement(tool, "Arrays")  # the schema allows one element inside a Tool
        for v in arrays:
            ET.SubElement(holder, "Array", {
                "name": v.name, "causality": v.causality, "shape": " ".join(map(str, v.shape)),
                "element": v.element, "unit": v.unit, "description": v.description,
                **({"dependsOn": " ".join(v.depends_on)} if v.depends_on is not None else {})})

    model_variables = ET.SubElement(root, "ModelVariables")
    for reference, v in enumerate(scalars):
        attributes = {"name": v.name, "valueReference": str(reference), "causality": v.causality,
                      "description": v.description}
        if v.type != "Real" and v.causality != "parameter":
            attributes["variability"] = "discrete"
        else:
            attributes["variability"] = VARIABILITY[v.causality]
        typed = {}
        if v.causality in ("output", "local"):
            attributes["initial"] = "calculated"
        elif v.start is not None:
            if v.causality == "parameter":
                attributes["initial"] = "exact"
            typed["start"] = xml_value(v.start.item() if hasattr(v.start, "item") else v.start)
        typed.update(typed_attributes(v))
        element = ET.SubElement(model_variables, "ScalarVariable", attributes)
        ET.SubElement(element, v.type, typed)

    root.append(model_structure(scalars))
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
