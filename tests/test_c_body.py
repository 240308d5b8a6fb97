"""A body written in C (bodies/kinematic_c): built with gcc and fmpy's FMI headers, valid, and the same body as the
Python kinematic arm - under fmpy's own master, under this master, and through `rhi experiment --body`."""
import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from fmpy.validation import validate_fmu

from rhi.components.body.variants import KinematicArm
from rhi.components.body.contract import BODY_CONTRACT
from rhi.components.fmu import FMUComponent
from rhi.master import ConfigError
from rhi.master.export.body import build_fmu
from rhi.master.export.c_body import build_c_fmu
from tests.in_process import rhi_in_process
from tests.test_fmu import OUTPUTS, run, under_fmpy


@pytest.fixture(scope="module")
def bodies(tmp_path_factory):
    folder = tmp_path_factory.mktemp("c_body")
    return {"c": build_c_fmu(folder / "KinematicC.fmu"), "python": build_fmu(folder / "Kinematic.fmu", "kinematic")}


def test_the_c_fmu_is_valid_and_declares_what_the_python_arm_declares(bodies):
    assert validate_fmu(str(bodies["c"])) == []
    def declarations(component):  # outputs are "calculated" in FMI: no start value to compare
        return {name: (v.causality, v.type, v.unit, v.min, v.max, v.depends_on,
                       None if v.causality == "output" else v.start) for name, v in component.variables.items()}

    assert declarations(FMUComponent(bodies["c"], "body", BODY_CONTRACT)) == declarations(KinematicArm())


@pytest.mark.parametrize("held", [False, True])
def test_under_fmpy_the_c_body_is_the_python_kinematic_arm(bodies, held):
    alone, python = under_fmpy(bodies["c"], held), run(KinematicArm(), held)
    for name in OUTPUTS:
        np.testing.assert_allclose(alone[name], python[name][:, 0], rtol=0, atol=1e-12)
    if held:  # the statics, not a copy of zeros: the arm pushes
        assert np.hypot(alone["force_x"][-1], alone["force_y"][-1]) > 0.1
    else:  # 0.5 deg/s for 0.6 s, exactly
        assert alone["q_shoulder"][-1] - alone["q_shoulder"][0] == pytest.approx(0.3, abs=1e-12)


def test_through_the_master_per_trial(bodies):
    trials = dict(held=np.array([False, True, True]), u_shoulder=np.array([0.5, 0.5, -1.0]),
                  u_elbow=np.array([0.0, 0.3, 1.0]), batch_size=3,
                  parameters={"body.q0_elbow": [-91.0, -95.0, -80.0], "body.servo_gain": [20.0, 5.0, 40.0]})
    c, python = run(FMUComponent(bodies["c"], "body", BODY_CONTRACT), **trials), run(KinematicArm(), **trials)
    for name in OUTPUTS:
        np.testing.assert_allclose(c[name], python[name], rtol=0, atol=1e-12)
    assert np.allclose(c["q_elbow"][0], [-91.0, -95.0, -80.0], atol=1e-12)  # the parameters reached the FMU


def rhi(*args, cache):
    """`rhi ARGS` in this process (tests/in_process.py): a conv-only run is one batch (no worker pool), and these
    FMUs load in this process above already; a subprocess would add seconds of imports to each run."""
    done = rhi_in_process(list(args), Path.cwd(), {"RHI_CACHE": str(cache)})
    return subprocess.CompletedProcess(["rhi", *args], done.status, done.stdout, done.stderr)


def test_rhi_experiment_with_the_c_body_gives_the_python_kinematic_summary(bodies, tmp_path, quick_cache):
    config = tmp_path / "conv.toml"
    config.write_text('[experiment]\ndecoders = ["conv"]\n')
    summaries = {}
    for kind, path in bodies.items():
        done = rhi("experiment", "--quick", "--config", str(config), "--body", str(path),
                   "--out", str(tmp_path / kind), cache=quick_cache)
        assert done.returncode == 0, done.stderr[-2000:]
        with open(tmp_path / kind / "summary.csv") as file:
            summaries[kind] = list(csv.DictReader(file))
    assert len(summaries["c"]) == 6 and [list(r) for r in summaries["c"]] == [list(r) for r in summaries["python"]]
    for c, python in zip(summaries["c"], summaries["python"]):
        for key, value in c.items():
            if key in ("decoder", "condition", "stimulation"):
                assert value == python[key]
            else:
                assert float(value) == pytest.approx(float(python[key]), rel=1e-9, abs=1e-12), key
    left = next(r for r in summaries["c"] if (r["condition"], r["stimulation"]) == ("left", "sync"))
    assert float(left["force_n_mean"]) < 0  # the statics of the brain's push toward the rubber hand


def test_a_bad_output_path_is_named(tmp_path):
    with pytest.raises(ConfigError, match=".fmu"):
        build_c_fmu(tmp_path / "body.zip")
    with pytest.raises(ConfigError):
        build_c_fmu(tmp_path / "no" / "such" / "body.fmu")


def test_rhi_export_body_builds_the_c_variant(tmp_path):
    done = subprocess.run([sys.executable, "-m", "rhi", "export-body", "--variant", "kinematic-c", "--out",
                           str(tmp_path / "C.fmu")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "variant kinematic-c" in done.stdout and validate_fmu(str(tmp_path / "C.fmu")) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["C.fmu"]  # written whole, nothing left beside it
