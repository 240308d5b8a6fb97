"""The published numbers on any x86-64 CPU: the shipped default decoders on a short protocol give the shipped
reference table (tests/reference/short_protocol.csv, made on an AVX-512 CPU) within the float32 arithmetic's
worst case, whichever kernels torch, oneDNN and numpy pick (`.ci/run` runs this under the AVX2 and the
baseline kernels as well); and run.json names the CPU."""
import json
import os

import numpy as np
import pytest

from rhi.master.tasks.illusion import fast_check
from rhi.master.outputs.provenance import VECTOR_EXTENSIONS, cpu_description
from tests import cross_cpu

# The decoder's sums that differ between kernels run over at most its 64 x 64 pixels (J^T e; a layer's
# reduction over channels x kernel is shorter), each within N u of the sum's magnitude. The closed loop
# is contracting (the proprioceptive pull), so a relative error of the visual drive moves the drift and the
# force it balances by at most as much, not compounding over the steps.
PIXELS, U32 = 64 * 64, 2.0 ** -24


@pytest.fixture(scope="module")
def here_and_reference():
    here, reference = cross_cpu.outcomes(), cross_cpu.read()
    assert [[row[key] for key in cross_cpu.KEYS] for row in here] == [[row[key] for key in cross_cpu.KEYS]
                                                                      for row in reference]
    return here, reference


def columns(rows, mode, kind, name):
    return np.array([row[name] for row in rows if (row["mode"], row["decoder"]) == (mode, kind)])


def test_the_exact_decoder_gives_the_reference_table_within_the_float32_bound(here_and_reference):
    here, reference = here_and_reference
    for kind in ("conv", "vae"):
        for name in ("drift_cm", "force_x_n"):
            want, got = columns(reference, "exact", kind, name), columns(here, "exact", kind, name)
            np.testing.assert_array_less(np.abs(got - want), PIXELS * U32 * np.abs(want).max(),
                                         err_msg=f"{kind} {name}")
        drift = dict(zip(("left", "center", "right"), columns(reference, "exact", kind, "drift_cm")[::2]))
        assert drift["left"] < -0.01 and drift["right"] > 0.01, drift  # sync: a drift to compare (not vacuous)


def test_the_fast_decoder_gives_the_reference_table_within_twice_its_guaranteed_error(here_and_reference):
    """Fast mode relinearises the decoder when the belief has moved a set distance; on another CPU that can
    fall a step earlier or later, so its numbers differ by more than the arithmetic's. What it guarantees is
    the fast check's bound: every drift within DRIFT_BOUND of the largest exact one, here as on the
    reference's CPU, so the two within twice that (the exact ones agreeing within N u, above)."""
    here, reference = here_and_reference
    for kind in ("conv", "vae"):
        for name in ("drift_cm", "force_x_n"):
            want, got = columns(reference, "fast", kind, name), columns(here, "fast", kind, name)
            np.testing.assert_array_less(np.abs(got - want),
                                         (2 * fast_check.DRIFT_BOUND + PIXELS * U32) * np.abs(want).max(),
                                         err_msg=f"{kind} {name}")
        drift = dict(zip(("left", "center", "right"), columns(reference, "fast", kind, "drift_cm")[::2]))
        assert drift["left"] < -0.5 and drift["right"] > 0.5 and abs(drift["center"]) < 0.1, drift  # the pattern


def test_gamma_is_the_reference_s_to_the_float64_rounding_of_its_updates(here_and_reference):
    """gamma depends on the event times alone (numpy, float64), not on the decoder: each of its updates'
    exp within a few ulp on any of numpy's SIMD paths (4 ulp taken), over at most STEPS updates."""
    here, reference = here_and_reference
    for mode in cross_cpu.STEPS:
        for kind in ("conv", "vae"):
            np.testing.assert_allclose(columns(here, mode, kind, "gamma"), columns(reference, mode, kind, "gamma"),
                                       rtol=cross_cpu.STEPS[mode] * 4 * np.finfo(float).eps, atol=0)
    sync = [row["gamma"] > 0.5 for row in reference if row["mode"] == "fast" and row["stimulation"] == "sync"]
    assert all(sync) and len(sync) == 6  # the reference shows the illusion


def test_run_json_names_the_cpu_and_its_vector_extensions(monkeypatch):
    chosen = os.environ.get("ATEN_CPU_CAPABILITY")
    if chosen:  # under tests.kernels: torch took the kernels asked for
        assert cpu_description()["torch_kernels"] == chosen.upper()
    monkeypatch.setenv("ATEN_CPU_CAPABILITY", "avx2")
    described = cpu_description()
    assert described["model"] and set(described["vector_extensions"]) <= set(VECTOR_EXTENSIONS)
    assert described["ATEN_CPU_CAPABILITY"] == "avx2"  # an override is recorded with the numbers
    with open("/proc/cpuinfo", encoding="utf-8") as file:
        flags = next(line for line in file if line.startswith("flags")).split(":")[1].split()
    assert described["vector_extensions"] == [name for name in VECTOR_EXTENSIONS if name in flags]
    assert json.loads(json.dumps(described)) == described  # goes into run.json as it is
