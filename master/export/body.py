"""``rhi export-body``: the body plant as a co-simulation FMU: FMI 2.0, built with pythonfmu, or FMI 3.0, built
with pythonfmu3 (the C body, :mod:`rhi.master.export.c_body`, for either).

The FMU carries its own copy of the ``components`` package (Python sources
only) next to the slave script (``components/body/fmu_slave.py``; for FMI 3.0
``components/body/fmu_slave3.py``, its ports the body contract's arrays,
``rhi.components.body.contract.FMI3_ARRAYS``), so it runs without this checkout, in
any Python that has numpy and pymunk (the builder puts its runtime in the FMU). A
resource file tells the slave which component class to wrap.

Example::

    build_fmu("Body.fmu", "kinematic")   # or: rhi export-body --variant kinematic --out Body.fmu
    build_fmu("Body3.fmu", fmi="3.0")    # or: rhi export-body --fmi 3.0 --out Body3.fmu
"""
from __future__ import annotations

import importlib
import importlib.util
import shutil
import tempfile
from pathlib import Path

from rhi.components.fmi_export.bundle import COMPONENT_FILE
from rhi.master.config.bodies import VARIANTS
from rhi.master.cosim import ConfigError
from rhi.master.export.fmu_files import build_with_pythonfmu, built_beside, check_target, staged_script

C_VARIANT = "kinematic-c"  # the kinematic arm written in C (master/export/c_body.py)
VARIANT_NAMES = (*VARIANTS, C_VARIANT)
FMI_VERSIONS = ("2.0", "3.0")  # every variant is built for both
PACKAGE = Path(__file__).resolve().parents[2] / "components"
SLAVES = {"2.0": "fmu_slave.py", "3.0": "fmu_slave3.py"}  # the slave script of each version, in components/body
# What a slave script takes in when it is imported, besides itself: the FMI export code and the description writer.
SLAVE_LOADS = sorted((PACKAGE / "fmi_export").glob("*.py")) + [PACKAGE / "model_description.py"]


def build_fmu(out, variant: str = "native", component: str | None = None, model_name: str | None = None,
              extra_files=(), fmi: str = "2.0") -> Path:
    """Build an FMU at ``out`` (a path ending in .fmu) and return its path.

    variant: a name in VARIANTS; ``component`` (``module:Class``) and ``model_name`` override it,
    with ``extra_files`` (Python modules that define that class) bundled next to the slave. fmi: ``2.0``
    (pythonfmu) or ``3.0`` (pythonfmu3; the component must declare the body contract's pairs, which become arrays).
    """
    check_fmi(variant, fmi)
    out = check_target(out)
    if variant not in VARIANTS:
        raise ConfigError(f"--variant {variant!r} is not one of {', '.join(VARIANT_NAMES)}")
    model_name = model_name or VARIANTS[variant][0]
    component = component or VARIANTS[variant][1]
    if not model_name.isidentifier():
        raise ConfigError(f"model name {model_name!r} must be an identifier (it names the FMU's library)")
    return built_beside(out, lambda target: _build(target, model_name, component, extra_files, fmi))


def check_fmi(variant: str, fmi: str) -> None:
    """ConfigError, in one line, unless ``variant`` can be built for FMI ``fmi`` here: a version of FMI_VERSIONS,
    and for FMI 3.0 of a pythonfmu variant, pythonfmu3 installed."""
    if fmi not in FMI_VERSIONS:
        raise ConfigError(f"--fmi {fmi!r} is not one of {', '.join(FMI_VERSIONS)}")
    if fmi == "3.0" and variant in VARIANTS and importlib.util.find_spec("pythonfmu3") is None:
        raise ConfigError(f"--fmi 3.0 --variant {variant} needs pythonfmu3 (pip install pythonfmu3==0.3.4, in the "
                          "test extra)")


def export_body(out, variant: str = "native", fmi: str = "2.0") -> Path:
    """The body FMU of ``variant`` for FMI ``fmi`` (2.0 or 3.0) at ``out``: a pythonfmu or pythonfmu3 one
    (VARIANTS), or the body written in C (C_VARIANT)."""
    check_fmi(variant, fmi)
    if variant == C_VARIANT:
        from rhi.master.export.c_body import build_c_fmu
        return build_c_fmu(out, fmi)
    return build_fmu(out, variant, fmi=fmi)


def _build(target: Path, model_name: str, component: str, extra_files, fmi: str) -> Path:
    script = SLAVES[fmi]
    with tempfile.TemporaryDirectory(prefix="rhi_export_") as staging:
        staging = Path(staging)
        # One prefix for both versions (master/export/own_files.py knows it); the content's hash tells them apart.
        script = staged_script(PACKAGE / "body" / script, staging, "rhi_fmu_slave",
                               loads=SLAVE_LOADS)
        # Python sources only: no caches, checkpoints or data files in the FMU.
        shutil.copytree(PACKAGE, staging / "components",
                        ignore=lambda folder, names: [n for n in names if not (
                            n.endswith(".py") or (Path(folder) / n).is_dir()) or n == "__pycache__"])
        spec = staging / COMPONENT_FILE
        spec.write_text(f"{model_name} {component}\n")
        return build_with_pythonfmu(script, target, [staging / "components", spec, *map(Path, extra_files)],
                                    f"the {model_name} FMU from {component}", fmi)
