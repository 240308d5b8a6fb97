"""What every result records of where it came from: package versions, the platform and the CPU."""
from __future__ import annotations

import json
import os
import platform
import sys
from importlib import metadata
from pathlib import Path

from rhi.master.outputs.atomic import atomic_write

PACKAGES = ("numpy", "scipy", "torch", "pymunk", "pillow", "fmpy", "pythonfmu", "matplotlib", "dask", "rhi")

# The CPU features that choose torch's, oneDNN's and numpy's kernels, and so the last bits of a result.
VECTOR_EXTENSIONS = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512bw", "avx512vl", "avx512_vnni",
                     "avx512_bf16", "avx512_fp16", "amx_tile")
KERNEL_SETTINGS = ("ATEN_CPU_CAPABILITY", "DNNL_MAX_CPU_ISA", "OPENBLAS_CORETYPE")  # environment overrides


def cpu_description() -> dict:
    """The CPU a result came from: its model, which of VECTOR_EXTENSIONS it has, the kernels torch runs
    (ATen's CPU capability, when torch is loaded) and the environment variables that override them."""
    model, flags = platform.processor() or platform.machine(), set()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as file:
            for line in file:
                key, _, value = line.partition(":")
                if key.strip() == "model name":
                    model = value.strip()
                elif key.strip() == "flags":
                    flags = set(value.split())
                    break
    except OSError:
        pass  # not Linux: the model from platform, the extensions unknown
    described = {"model": model, "vector_extensions": [name for name in VECTOR_EXTENSIONS if name in flags]}
    if "torch" in sys.modules:
        described["torch_kernels"] = sys.modules["torch"].backends.cpu.get_cpu_capability()
    described.update({name: os.environ[name] for name in KERNEL_SETTINGS if name in os.environ})
    return described


def package_versions() -> dict:
    """The versions of Python and of the installed ``PACKAGES``, the platform and the CPU (:func:`cpu_description`)."""
    versions = {"python": sys.version.split()[0], "platform": platform.platform(), "cpu": cpu_description()}
    for package in PACKAGES:
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            pass
    return versions


def write_run_record(folder: str | os.PathLike, record: dict) -> None:
    """run.json in ``folder``: what a result records of where it came from, whole or not at all. The one writer of
    every command's run.json (a task's folder, a fit, a power analysis).

    Parameters
    ----------
    folder : the folder (a staging folder, or a fit's own) that receives run.json.
    record : JSON-able values; anything else (a path, a numpy scalar) is written as its ``str``.
    """
    atomic_write(Path(folder) / "run.json", json.dumps(record, indent=2, default=str) + "\n")
