"""Run the numeric tests again under the kernels of other x86-64 CPUs, on this one.

    python -m tests.kernels [--all] [pytest arguments]   # `make test-kernels`, which .ci/run runs after `make test`

By default under one set, the next below this CPU's own (AVX-512 -> AVX2, AVX2 -> baseline): the other CPU kind
this project's machines are; ``--all`` under every set below this CPU's own.

torch, oneDNN and numpy each pick their vector kernels at run time, and each can be told to take a lesser
set: torch by ATEN_CPU_CAPABILITY, oneDNN (torch's convolutions) by DNNL_MAX_CPU_ISA, MKL (its matrix
products) by MKL_ENABLE_INSTRUCTIONS, numpy by NPY_DISABLE_CPU_FEATURES. An AVX-512 machine so computes what an AVX2 one (the AMD EPYC) does, and either
what a machine with the baseline kernels does; the sums come out rounded as there. OpenBLAS's kernel choice
(OPENBLAS_CORETYPE) is left to the machine's settings.
"""
from __future__ import annotations

import os
import subprocess
import sys

# The numeric tests whose numbers come through float32 kernels: the decoders, their contracts with the
# brain, fast mode, batching, training, the published numbers' reference table, the pose encoders; and the
# arm's C sub-steps against numpy's element-wise kernels (whose choice between +0 and -0 the C copies).
NUMERIC = ("tests/test_reproducibility.py", "tests/test_contracts.py", "tests/test_fast.py", "tests/test_batching.py",
           "tests/test_vision.py", "tests/test_training.py", "tests/test_brain.py", "tests/test_fast_grouped.py",
           "tests/test_body_cloop.py", "tests/test_ownership_pose.py")

# Each tier: torch's capability, oneDNN's ISA, MKL's (torch's matrix products), and numpy's feature groups
# above it (disabled where present).
TIERS = {
    "avx2": ("avx2", "AVX2", "AVX2", ("X86_V4", "AVX512_ICL", "AVX512_SPR")),
    "default": ("default", "SSE41", "SSE4_2", ("X86_V3", "X86_V4", "AVX512_ICL", "AVX512_SPR")),
}


def environment(tier: str) -> dict[str, str]:
    """os.environ with ``tier``'s settings; numpy is told to disable only groups this CPU has (it refuses
    to disable what it did not find)."""
    from numpy._core._multiarray_umath import __cpu_features__

    capability, isa, mkl, groups = TIERS[tier]
    disabled = " ".join(group for group in groups if __cpu_features__.get(group))
    settings = {"ATEN_CPU_CAPABILITY": capability, "DNNL_MAX_CPU_ISA": isa, "MKL_ENABLE_INSTRUCTIONS": mkl}
    if disabled:
        settings["NPY_DISABLE_CPU_FEATURES"] = disabled
    return {**os.environ, **settings}


def tiers_below_this_cpu() -> list[str]:
    """The tiers of :data:`TIERS` below the kernels torch picks on this CPU, highest first."""
    import torch

    native = torch.backends.cpu.get_cpu_capability().lower()  # "avx512", "avx2" or "default"
    order = ["avx512", "avx2", "default"]
    return [tier for tier in order[order.index(native) + 1:] if tier in TIERS] if native in order else list(TIERS)


def main(arguments: list[str]) -> int:
    every = "--all" in arguments
    arguments = [argument for argument in arguments if argument != "--all"]
    below = tiers_below_this_cpu()
    status = 0
    for tier in below if every else below[:1]:
        print(f"== the numeric tests under the {tier} kernels", flush=True)
        done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "2", "--dist",
                               "loadfile", *NUMERIC, *arguments],
                              env=environment(tier))
        status = status or done.returncode
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
