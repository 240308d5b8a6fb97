"""The body variants rhi ships, by name: what ``rhi experiment --body NAME`` and a configuration's
``experiment.body`` run in this process, and what ``rhi export-body --variant NAME`` packs into an FMU.

Each names its FMI model identifier and its component class as ``module:Class`` under ``components``: the name
the class has in an FMU's own copy of that folder (master/export/body.py), and under ``rhi.components`` here.
"""
from __future__ import annotations

import importlib

from rhi.master.cosim import ConfigError

# variant -> (model name, which is also the FMI model identifier; component class as module:Class)
VARIANTS = {
    "native": ("ArmBody", "components.body.plant:ArmPlant"),
    "kinematic": ("KinematicArmBody", "components.body.variants:KinematicArm"),
    "batched": ("BatchedArmBody", "components.body.batched:BatchedArm"),  # the pymunk arm's, vectorised for cohorts
}

DEFAULT = "native"  # experiment.body's default: the pymunk arm, the task's own plant


def configured(config: dict) -> str | None:
    """The body variant ``config`` chooses (``experiment.body``), None for the default pymunk arm, so that the
    default runs exactly the path it always ran."""
    name = config["experiment"].get("body", DEFAULT)
    return None if name == DEFAULT else name


def check(config: dict) -> None:
    """ConfigError unless ``experiment.body`` names a body variant of :data:`VARIANTS`."""
    name = config["experiment"].get("body", DEFAULT)
    if name not in VARIANTS:
        raise ConfigError(f"experiment.body = {str(name)[:60]!r} is not a body variant; choose one of "
                          f"{', '.join(VARIANTS)} (an FMU is given with rhi experiment --body FMU)")


def variant_class(name: str):
    """The component class of body variant ``name`` (:data:`VARIANTS`), to run in this process (``rhi experiment
    --body batched``); None when ``name`` names none (an FMU's path)."""
    if name not in VARIANTS:
        return None
    module, _, attribute = VARIANTS[name][1].partition(":")
    return getattr(importlib.import_module(f"rhi.{module}"), attribute)
