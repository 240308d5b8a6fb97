"""The body variants rhi ships, by name: what ``rhi experiment --body NAME`` runs in this process and what
``rhi export-body --variant NAME`` packs into an FMU.

Each names its FMI model identifier and its component class as ``module:Class`` under ``components``: the name
the class has in an FMU's own copy of that folder (master/export/body.py), and under ``rhi.components`` here.
"""
from __future__ import annotations

import importlib

# variant -> (model name, which is also the FMI model identifier; component class as module:Class)
VARIANTS = {
    "native": ("ArmBody", "components.body.plant:ArmPlant"),
    "kinematic": ("KinematicArmBody", "components.body.variants:KinematicArm"),
    "batched": ("BatchedArmBody", "components.body.batched:BatchedArm"),  # the pymunk arm's, vectorised for cohorts
}


def variant_class(name: str):
    """The component class of body variant ``name`` (:data:`VARIANTS`), to run in this process (``rhi experiment
    --body batched``); None when ``name`` names none (an FMU's path)."""
    if name not in VARIANTS:
        return None
    module, _, attribute = VARIANTS[name][1].partition(":")
    return getattr(importlib.import_module(f"rhi.{module}"), attribute)
