"""Run the numeric tests again under the kernels of other x86-64 CPUs, on this one.

    python -m tests.kernels [pytest arguments]    # `make test-kernels`, which .ci/run runs after `make test`

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
# brain, fast mode, batching, training, and the published numbers' reference table.
NUMERIC = ("tests/test_reproducibility.py", "tests/test_contracts.py", "tests/test_fast.py", "tests/test_batching.py",
           "tests/test_vision.py", "tests/test_training.py", "tests/test_brain.py")

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


def main(arguments: list[str]) -> int:
    status = 0
    for tier in TIERS:
        print(f"== the numeric tests under the {tier} kernels", flush=True)
        done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "2", "--dist",
                               "loadfile", *NUMERIC, *arguments],
                              env=environment(tier))
        status = status or done.returncode
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
