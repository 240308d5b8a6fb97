"""Declared variables of a component: the Python twin of an FMI 2.0 ScalarVariable.

A component lists its variables once, as class data. The master reads the
declarations to validate a system before it runs; the model-description view
(:mod:`rhi.components.model_description`) turns them into a ``modelDescription.xml``.

Every value carries a leading batch dimension B (independent trials advancing
together): a scalar holds an array of shape ``(B,)``. ``Array`` is the port
FMI 2.0 cannot carry (a joint vector, an image): an ``Array`` of ``shape=(2,)``
holds ``(B, 2)`` values of its ``element`` type (float64 or float32). A
component's variables may depend on its structural constructor arguments (the
camera's resolution fixes the image shape), so they are declared per instance.

Example::

    Variable("q_shoulder", "output", "Real", unit="deg",
             description="shoulder angle of the upper arm from +x", depends_on=())
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CAUSALITIES = ("parameter", "input", "output", "local")
TYPES = ("Real", "Integer", "Boolean", "Array")
DTYPES = {"Real": np.float64, "Integer": np.int64, "Boolean": np.bool_}
ELEMENTS = {"float64": np.float64, "float32": np.float32}


@dataclass(frozen=True)
class Variable:
    """One declared variable.

    name: unique within the component.
    causality: ``parameter`` (fixed before the run), ``input``, ``output`` or ``local``.
    type: ``Real``, ``Integer``, ``Boolean`` (scalars) or ``Array``.
    shape: per-trial shape of an ``Array``; ``()`` for the scalar types.
    element: element type of an ``Array``: ``float64`` or ``float32``.
    start: start value (broadcast over the batch); ``None`` means no start value,
        allowed only for inputs, which must then be connected.
    unit: SI-style unit string ("m", "deg", "deg/s", "N", "s", "1").
    description: one line, what it means.
    min, max: the admissible range (inclusive), checked on set for parameters.
    depends_on: for outputs, the inputs it depends on directly within a step
        (FMI ModelStructure). ``None`` means every input (the conservative FMI
        default); ``()`` means the output is state and depends on no input now.
    """

    name: str
    causality: str
    type: str = "Real"
    shape: tuple[int, ...] = ()
    start: object = 0.0
    unit: str = ""
    description: str = ""
    min: float | None = None
    max: float | None = None
    depends_on: tuple[str, ...] | None = None
    element: str = "float64"

    def __post_init__(self):
        if self.causality not in CAUSALITIES:
            raise ValueError(f"variable {self.name!r}: causality {self.causality!r} is not one of {CAUSALITIES}")
        if self.type not in TYPES:
            raise ValueError(f"variable {self.name!r}: type {self.type!r} is not one of {TYPES}")
        if (self.type == "Array") != bool(self.shape):
            raise ValueError(f"variable {self.name!r}: an Array needs a shape and only an Array has one")
        if self.element not in ELEMENTS:
            raise ValueError(f"variable {self.name!r}: element {self.element!r} is not one of {tuple(ELEMENTS)}")
        if self.depends_on is not None and self.causality != "output":
            raise ValueError(f"variable {self.name!r}: only outputs declare depends_on")

    @property
    def dtype(self):
        """The numpy dtype of a value: an Array's ``element``, else the scalar type's (float64, int64, bool)."""
        return ELEMENTS[self.element] if self.type == "Array" else DTYPES[self.type]

    @property
    def kind(self) -> str:
        """``Real``, or ``Array[8, 8] float32``: the type as error messages name it."""
        return f"Array{list(self.shape)} {self.element}" if self.type == "Array" else self.type


@dataclass(frozen=True)
class ContractVariable:
    """A variable an FMU must have: name, causality, FMI type and unit ('' for none)."""

    name: str
    causality: str
    type: str
    unit: str = ""
