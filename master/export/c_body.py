"""A body written in C, built into an FMI 2.0 or FMI 3.0 co-simulation FMU with gcc and the FMI headers fmpy ships.

The source, ``bodies/kinematic_c/kinematic_arm.c``, is the ideal kinematic arm of
:class:`rhi.components.body.variants.KinematicArm` (free: q follows the command; held: the servo's
statics give the hand force); ``-DFMI_VERSION=3`` selects its FMI 3.0 interface. Its
``modelDescription.xml`` is written from the Python arm's own declarations, for FMI 2.0
(:mod:`rhi.components.model_description`) or FMI 3.0 (:mod:`rhi.components.fmi_export.description_fmi3`, the pairs in
ARRAYS as Float64 arrays), and its start values and FMI 3.0 array sizes are compiled in from the same
declarations, so the bodies declare the same variables, units, ranges and starts.

Example::

    build_c_fmu("KinematicC.fmu")     # then: rhi experiment --body KinematicC.fmu
    build_c_fmu("KinematicC3.fmu", fmi="3.0")
"""
from __future__ import annotations

import errno
import os
import shutil
import subprocess
import tempfile
import zipfile
from pathlib import Path

from rhi.components.body.contract import FMI3_ARRAYS
from rhi.components.body.variants import KinematicArm
from rhi.components.fmi_export.description_fmi3 import sizes, to_xml3
from rhi.master.cosim import ConfigError
from rhi.master.export.fmu_files import check_target
from rhi.master.outputs.files import atomic_write
from rhi.master.outputs.out_file import place_file

SOURCE = Path(__file__).resolve().parents[2] / "bodies" / "kinematic_c" / "kinematic_arm.c"
MODEL_IDENTIFIER = "KinematicArmC"  # the FMI model identifier, which names the shared library
STARTS = ("q0_shoulder", "q0_elbow", "servo_gain", "torque_limit", "held")  # compiled in as START_<NAME>
FMI_VERSIONS = ("2.0", "3.0")
ARRAYS = FMI3_ARRAYS  # the FMI 3.0 arrays (the body contract's): name -> (description, the scalars it carries)


def declared_body() -> KinematicArm:
    """The Python arm whose declarations the C body's descriptions, starts and array sizes are written from."""
    return KinematicArm(name=MODEL_IDENTIFIER)


def compile_flags(component: KinematicArm, fmi: str = "2.0") -> list[str]:
    """``-DSTART_NAME=value`` for each parameter's declared start value (repr: every digit of a float); for FMI
    3.0, ``-DFMI_VERSION=3`` and the elements behind each value reference (``-DVARIABLE_SIZES={2,0,...}``)."""
    flags = [] if fmi == "2.0" else ["-DFMI_VERSION=3",
                                     "-DVARIABLE_SIZES={%s}" % ",".join(map(str, sizes(component, ARRAYS)))]
    for name in STARTS:
        start = component.variables[name].start
        flags.append(f"-DSTART_{name.upper()}={int(start) if isinstance(start, bool) else repr(float(start))}")
    return flags


# What a compiler's messages say when the machine, not the source, stopped it: a program of its killed (by a
# file-size limit, SIGXFSZ, or the kernel's OOM killer), or a write refused for want of space
STOPPED = ("terminated program", "Killed signal", "File size limit exceeded", "File too large",
           "No space left on device", "Disk quota exceeded")


def build_c_fmu(out: str | os.PathLike, fmi: str = "2.0") -> Path:
    """Compile the C body for FMI ``fmi`` (2.0 or 3.0) and write the FMU at ``out`` (a path ending in .fmu),
    whole or not at all."""
    import fmpy

    if fmi not in FMI_VERSIONS:
        raise ConfigError(f"--fmi {fmi!r} is not one of {', '.join(FMI_VERSIONS)}")
    out = check_target(out)
    compiler = os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")
    if not compiler:
        raise ConfigError("no C compiler found (set CC, or install gcc) to build the C body")
    component = declared_body()
    headers = Path(fmpy.__file__).parent / "c-code"
    platform = fmpy.platform if fmi == "2.0" else fmpy.platform_tuple  # FMI 3.0 names folders e.g. x86_64-linux
    binary = f"binaries/{platform}/{MODEL_IDENTIFIER}{fmpy.sharedLibraryExtension}"
    with tempfile.TemporaryDirectory(prefix="rhi_c_body_") as folder:
        library = Path(folder) / "library"
        done = subprocess.run([compiler, "-shared", "-fPIC", "-O2", "-std=c99", "-Wall", "-Werror",
                               "-Wno-unused-parameter", f"-I{headers}", *compile_flags(component, fmi), str(SOURCE),
                               "-o", str(library), "-lm"], capture_output=True, text=True)
        if done.returncode:
            errors = [line for line in done.stderr.splitlines() if "error" in line] or done.stderr.splitlines()
            first = errors[0].strip() if errors else ""
            stopped = next((line.strip() for line in done.stderr.splitlines() if any(s in line for s in STOPPED)), "")
            if done.returncode < 0 or stopped:  # killed (a file-size or memory limit) or out of disk: the machine's
                how = stopped or f"killed by signal {-done.returncode}"
                raise OSError(errno.EIO, f"compiling {SOURCE.name} with {compiler} was stopped by this machine "
                                         f"({how})", str(out))
            raise ConfigError(f"compiling {SOURCE.name} with {compiler} failed: {first}")

        def write(file):
            with zipfile.ZipFile(file, "w", zipfile.ZIP_DEFLATED) as archive:
                archive.writestr("modelDescription.xml", component.model_description() if fmi == "2.0"
                                 else to_xml3(component, ARRAYS))
                archive.write(library, binary)

        atomic_write(out, write, place_file)  # never over a file that appeared at out meanwhile
    return out
