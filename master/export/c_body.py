"""A body written in C, built into an FMI 2.0 co-simulation FMU with gcc and the FMI headers fmpy ships.

The source, ``bodies/kinematic_c/kinematic_arm.c``, is the ideal kinematic arm of
:class:`components.body.variants.KinematicArm` (free: q follows the command; held: the servo's
statics give the hand force). Its ``modelDescription.xml`` is the Python arm's own description
(:mod:`components.model_description`), and its start values are compiled in from the same
declarations, so the two bodies declare the same variables, units, ranges and starts.

Example::

    build_c_fmu("KinematicC.fmu")     # then: rhi experiment --body KinematicC.fmu
"""
from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import zipfile
from pathlib import Path

from components.body.variants import KinematicArm
from master.cosim import ConfigError
from master.export.fmu_files import check_target
from master.outputs.files import atomic_write

SOURCE = Path(__file__).resolve().parents[2] / "bodies" / "kinematic_c" / "kinematic_arm.c"
MODEL_IDENTIFIER = "KinematicArmC"  # the FMI model identifier, which names the shared library
STARTS = ("q0_shoulder", "q0_elbow", "servo_gain", "torque_limit", "held")  # compiled in as START_<NAME>


def compile_flags(component: KinematicArm) -> list[str]:
    """``-DSTART_NAME=value`` for each parameter's declared start value (repr: every digit of a float)."""
    flags = []
    for name in STARTS:
        start = component.variables[name].start
        flags.append(f"-DSTART_{name.upper()}={int(start) if isinstance(start, bool) else repr(float(start))}")
    return flags


def build_c_fmu(out: str | os.PathLike) -> Path:
    """Compile the C body and write the FMU at ``out`` (a path ending in .fmu), whole or not at all."""
    import fmpy

    out = check_target(out)
    compiler = os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")
    if not compiler:
        raise ConfigError("no C compiler found (set CC, or install gcc) to build the C body")
    component = KinematicArm(name=MODEL_IDENTIFIER)
    headers = Path(fmpy.__file__).parent / "c-code"
    binary = f"binaries/{fmpy.platform}/{MODEL_IDENTIFIER}{fmpy.sharedLibraryExtension}"
    with tempfile.TemporaryDirectory(prefix="rhi_c_body_") as folder:
        library = Path(folder) / "library"
        done = subprocess.run([compiler, "-shared", "-fPIC", "-O2", "-std=c99", "-Wall", "-Werror",
                               "-Wno-unused-parameter", f"-I{headers}", *compile_flags(component), str(SOURCE),
                               "-o", str(library), "-lm"], capture_output=True, text=True)
        if done.returncode:
            errors = [line for line in done.stderr.splitlines() if "error" in line] or done.stderr.splitlines()
            raise ConfigError(f"compiling {SOURCE.name} with {compiler} failed: {errors[0].strip() if errors else ''}")

        def write(file):
            with zipfile.ZipFile(file, "w", zipfile.ZIP_DEFLATED) as archive:
                archive.writestr("modelDescription.xml", component.model_description())
                archive.write(library, binary)

        atomic_write(out, write)
    return out
