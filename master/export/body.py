"""``rhi export-body``: the body plant as an FMI 2.0 co-simulation FMU, built with pythonfmu (the C body,
:mod:`master.export.c_body`, also as FMI 3.0).

The FMU carries its own copy of the ``components`` package (Python sources
only) next to the slave script ``components/body/fmu_slave.py``, so it runs
without this checkout, in any Python that has numpy, pymunk and pythonfmu's
runtime. A resource file tells the slave which component class to wrap.

Example::

    build_fmu("Body.fmu", "kinematic")   # or: rhi export-body --variant kinematic --out Body.fmu
"""
from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

from master.cosim import ConfigError
from master.export.fmu_files import build_with_pythonfmu, built_beside, check_target, staged_script

# variant -> (model name, which is also the FMI model identifier; component class as module:Class)
VARIANTS = {
    "native": ("ArmBody", "components.body.plant:ArmPlant"),
    "kinematic": ("KinematicArmBody", "components.body.variants:KinematicArm"),
}
C_VARIANT = "kinematic-c"  # the kinematic arm written in C (master/export/c_body.py)
VARIANT_NAMES = (*VARIANTS, C_VARIANT)
FMI_VERSIONS = {"2.0": VARIANT_NAMES, "3.0": (C_VARIANT,)}  # FMI version -> the variants built for it
PACKAGE = Path(__file__).resolve().parents[2] / "components"


def build_fmu(out, variant: str = "native", component: str | None = None, model_name: str | None = None,
              extra_files=()) -> Path:
    """Build an FMU at ``out`` (a path ending in .fmu) and return its path.

    variant: a name in VARIANTS; ``component`` (``module:Class``) and ``model_name`` override it,
    with ``extra_files`` (Python modules that define that class) bundled next to the slave.
    """
    out = check_target(out)
    if variant not in VARIANTS:
        raise ConfigError(f"--variant {variant!r} is not one of {', '.join(VARIANT_NAMES)}")
    model_name = model_name or VARIANTS[variant][0]
    component = component or VARIANTS[variant][1]
    if not model_name.isidentifier():
        raise ConfigError(f"model name {model_name!r} must be an identifier (it names the FMU's library)")
    return built_beside(out, lambda target: _build(target, model_name, component, extra_files))


def check_fmi(variant: str, fmi: str) -> None:
    """ConfigError, in one line, unless ``variant`` can be built for FMI ``fmi`` (FMI_VERSIONS)."""
    if fmi not in FMI_VERSIONS:
        raise ConfigError(f"--fmi {fmi!r} is not one of {', '.join(FMI_VERSIONS)}")
    if variant in VARIANT_NAMES and variant not in FMI_VERSIONS[fmi]:
        raise ConfigError(f"--fmi {fmi} is built for --variant {' or '.join(FMI_VERSIONS[fmi])} only; "
                          f"--variant {variant} is FMI 2.0 (pythonfmu)")


def export_body(out, variant: str = "native", fmi: str = "2.0") -> Path:
    """The body FMU of ``variant`` for FMI ``fmi`` at ``out``: a pythonfmu one (VARIANTS, FMI 2.0), or the body
    written in C (C_VARIANT, FMI 2.0 or 3.0)."""
    check_fmi(variant, fmi)
    if variant == C_VARIANT:
        from master.export.c_body import build_c_fmu
        return build_c_fmu(out, fmi)
    return build_fmu(out, variant)


def _build(target: Path, model_name: str, component: str, extra_files) -> Path:
    with tempfile.TemporaryDirectory(prefix="rhi_export_") as staging:
        staging = Path(staging)
        script = staged_script(PACKAGE / "body" / "fmu_slave.py", staging, "rhi_fmu_slave",
                               loads=[PACKAGE / "fmu_slave_base.py"])
        # Python sources only: no caches, checkpoints or data files in the FMU.
        shutil.copytree(PACKAGE, staging / "components",
                        ignore=lambda folder, names: [n for n in names if not (
                            n.endswith(".py") or (Path(folder) / n).is_dir()) or n == "__pycache__"])
        spec = staging / "rhi_component.txt"
        spec.write_text(f"{model_name} {component}\n")
        return build_with_pythonfmu(script, target, [staging / "components", spec, *map(Path, extra_files)],
                                    f"the {model_name} FMU from {component}")
