"""The model-description view for FMI 3.0: a component as an FMI 3.0 co-simulation ``modelDescription.xml``.

Written from the same declarations as the FMI 2.0 description (:mod:`rhi.components.model_description`), with
the same units, ranges, starts and dependencies; what differs is the grouping: ``arrays`` names runs of
scalars (consecutive in declaration order, alike in causality, unit and range) that FMI 3.0 carries as one
``Float64`` array each, with ``<Dimension start="n"/>``. Value references stay the FMI 2.0 ones: an array's is
its first element's, so an FMU can serve both versions from one table of values. FMI 3.0 asks for exactly one
independent variable: ``time``, whose value reference follows the last scalar's.

Example::

    to_xml3(KinematicArm(), {"q": ("joint angles", ("q_shoulder", "q_elbow"))})
"""
from __future__ import annotations

import uuid
from xml.etree import ElementTree as ET

from ..model_description import VARIABILITY, unit_definitions, xml_value

TYPES = {"Real": "Float64", "Integer": "Int32", "Boolean": "Boolean"}  # FMI 2.0 type -> FMI 3.0 element


def layout(component, arrays: dict) -> list[tuple[str, int, tuple, str]]:
    """The FMI 3.0 variables of ``component`` in value-reference order: (name, value reference, the declared
    variables it carries, description), without ``time``.

    arrays: {name: (description, member names)}; members must be consecutive Real scalars alike in causality,
    unit, range and dependencies (ValueError otherwise), so that one FMI 3.0 array stands for all of them.
    """
    scalars = list(component.variables.values())
    if any(v.type not in TYPES for v in scalars):
        raise ValueError(f"{component.name}: only Real, Integer and Boolean ports have an FMI 3.0 form here")
    position = {v.name: i for i, v in enumerate(scalars)}
    first = {}
    for name, (description, members) in arrays.items():
        at = [position.get(m) for m in members]
        if None in at or at != list(range(at[0], at[0] + len(members))):
            raise ValueError(f"array {name!r}: {members} are not consecutive declared variables")
        group = [scalars[i] for i in at]
        alike = {(v.causality, v.type, v.unit, v.min, v.max, v.depends_on) for v in group}
        if len(alike) != 1 or group[0].type != "Real":
            raise ValueError(f"array {name!r}: {members} differ in causality, type, unit, range or dependencies")
        first[at[0]] = (name, tuple(group), description)
    rows, inside = [], set()
    for reference, v in enumerate(scalars):
        if reference in first:
            name, group, description = first[reference]
            rows.append((name, reference, group, description))
            inside.update(g.name for g in group[1:])
        elif v.name not in inside:
            rows.append((v.name, reference, (v,), v.description))
    return rows


def sizes(component, arrays: dict) -> list[int]:
    """Elements per FMI 2.0 value reference in the FMI 3.0 layout: an array's length at its first element,
    0 at its other elements, 1 for a scalar."""
    counts = [0] * len(component.variables)
    for _, reference, group, _ in layout(component, arrays):
        counts[reference] = len(group)
    return counts


def to_xml3(component, arrays: dict) -> str:
    """The FMI 3.0 co-simulation model description of ``component``, ``arrays`` as in :func:`layout`."""
    rows = layout(component, arrays)
    time_reference = len(component.variables)
    carrier = {v.name: reference for _, reference, group, _ in rows for v in group}
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "3.0",
        "modelName": type(component).__name__,
        "instantiationToken": "{%s}" % uuid.uuid5(uuid.NAMESPACE_URL, repr(
            [(name, reference, [(v.name, v.causality, v.type, v.unit) for v in group]) for name, reference, group, _
             in rows])),
        "description": (type(component).__doc__ or "").strip().splitlines()[0] if type(component).__doc__ else "",
        "generationTool": "rhi",
        "variableNamingConvention": "flat",
    })
    ET.SubElement(root, "CoSimulation", {"modelIdentifier": component.name,
                                         "canHandleVariableCommunicationStepSize": "true"})
    root.append(unit_definitions(["s", *(v.unit for v in component.variables.values() if v.unit)]))  # s: time

    model_variables = ET.SubElement(root, "ModelVariables")
    ET.SubElement(model_variables, "Float64", {"name": "time", "valueReference": str(time_reference),
                                               "causality": "independent", "variability": "continuous",
                                               "description": "simulation time", "unit": "s"})
    outputs = []
    for name, reference, group, description in rows:
        v = group[0]
        # as in FMI 2.0: a non-Real port that is not a parameter changes only at communication points
        variability = "discrete" if v.type != "Real" and v.causality != "parameter" else VARIABILITY[v.causality]
        attributes = {"name": name, "valueReference": str(reference), "causality": v.causality,
                      "variability": variability, "description": description}
        if v.causality in ("output", "local"):
            attributes["initial"] = "calculated"
            outputs.append((reference, v))
        elif v.start is not None:
            if v.causality == "parameter":
                attributes["initial"] = "exact"
            attributes["start"] = " ".join(xml_value(m.start.item() if hasattr(m.start, "item") else m.start)
                                           for m in group)
        if v.type == "Real" and v.unit:
            attributes["unit"] = v.unit
        cast = {"Real": float, "Integer": int}.get(v.type)
        for bound in ("min", "max"):
            if getattr(v, bound) is not None and cast is not None:
                attributes[bound] = xml_value(cast(getattr(v, bound)))
        element = ET.SubElement(model_variables, TYPES[v.type], attributes)
        if len(group) > 1:
            ET.SubElement(element, "Dimension", {"start": str(len(group))})

    structure = ET.SubElement(root, "ModelStructure")
    inputs = [v.name for v in component.variables.values() if v.causality == "input"]
    for reference, v in outputs:
        sources = inputs if v.depends_on is None else v.depends_on  # None: every input (FMI's default)
        ET.SubElement(structure, "Output", {"valueReference": str(reference), "dependencies": " ".join(
            str(r) for r in dict.fromkeys(carrier[n] for n in sources if n in carrier))})
    for reference, _ in outputs:
        ET.SubElement(structure, "InitialUnknown", {"valueReference": str(reference)})
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
