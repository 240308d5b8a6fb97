"""A `--body` FMU whose native code ends the process: ``abort()`` when it is instantiated, a segfault in a step,
``_exit(0)`` in a step. rhi runs the experiment's simulation in a child process (rhi.master.runtime.contained), so each
is one error line, exit status 1, and nothing left beside DIR (docs/safety.md)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.faults import CONV_ONLY, ENV, experiment, expand

CRASHING_PLANTS = '''
import ctypes, os
from rhi.components.body.plant import ArmPlant


CRASH = os.environ.get("RHI_TEST_CRASH")  # only in the run under test: building the FMU instantiates it too


class AbortInInstantiate(ArmPlant):
    def instantiate(self, batch_size=1):
        if CRASH:
            os.abort()
        super().instantiate(batch_size)


class SegfaultInStep(ArmPlant):
    def step(self, t, h):
        if CRASH:
            ctypes.string_at(0)  # reads address 0: SIGSEGV
        super().step(t, h)


class ExitInStep(ArmPlant):
    def step(self, t, h):
        if CRASH:
            os._exit(0)
        super().step(t, h)
'''
PLANTS = ("AbortInInstantiate", "SegfaultInStep", "ExitInStep")


@pytest.fixture(scope="module")
def crashing_fmus(tmp_path_factory) -> dict:
    from rhi.master.export.body import build_fmu

    folder = tmp_path_factory.mktemp("crashing")
    (folder / "rhi_test_crashing_plants.py").write_text(CRASHING_PLANTS)
    return {name: str(build_fmu(folder / f"{name}.fmu", component=f"rhi_test_crashing_plants:{name}",
                                model_name=name, extra_files=[folder / "rhi_test_crashing_plants.py"]))
            for name in PLANTS}


@pytest.mark.parametrize("plant", PLANTS)
def test_a_body_fmu_that_ends_the_process_is_one_line_exit_1_and_nothing_left(plant, crashing_fmus,
                                                                             fault_resources, tmp_path):
    work = tmp_path / "work"
    work.mkdir()
    (work / "conv_only.toml").write_text(CONV_ONLY + "[decoder]\nfast = false\n")  # no fast-mode check: seconds
    args = [expand(a, fault_resources) for a in experiment("--body", crashing_fmus[plant], "--out", "out")]
    done = subprocess.run([sys.executable, "-m", "rhi", *args], cwd=work, capture_output=True, text=True,
                          env={**ENV, "RHI_TEST_CRASH": "1", "RHI_CACHE": str(tmp_path / "cache"),
                               "TMPDIR": str(tmp_path)}, timeout=300)
    lines = [line for line in done.stderr.splitlines() if "rhi experiment:" in line]
    assert done.returncode == 1, done.stderr[-3000:]
    assert len(lines) == 1 and lines[0].startswith("rhi experiment: error: ") and "ended abnormally" in lines[0], \
        done.stderr[-3000:]
    assert "Traceback" not in done.stderr
    assert sorted(os.listdir(work)) == ["conv_only.toml"]  # no out, no .out.lock, no .out.XXXXXXXX.partial
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith("rhi_")] == []  # no scratch folder left
