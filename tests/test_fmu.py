"""The body as an FMI 2.0 FMU: export with pythonfmu, run under fmpy and through the adapter, the contract.

Truth: the native ArmPlant (trajectories must agree to 1e-9), statics by finite differences of the
forward kinematics (the kinematic variant's held force), exact integration (its free motion), and
hand-made broken FMUs (each contract error).
"""
import os
import subprocess
import sys
import textwrap
import zipfile
from argparse import Namespace

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.validation import validate_fmu

from rhi.components.body.kinematics import REST_POSE, forward, jacobian
from rhi.components.body.plant import ArmPlant
from rhi.components.component import ComponentError
from rhi.components.body.contract import BODY_CONTRACT
from rhi.components.fmu import FMUComponent, check_contract, extracted, guard_library
from rhi.components.vision.component import Decoder
from rhi.master import ConfigError, SimulationError, System, simulate
from rhi.master.commands.export_body import run as run_export
from rhi.master.export.body import build_fmu
from tests.toys import Constant

OUTPUTS = ("q_shoulder", "q_elbow", "hand_x", "hand_y", "force_x", "force_y")
BROKEN_PLANTS = '''
import numpy as np
from components.body.plant import ArmPlant  # the FMU's own copy (resources/components)

class NanArmPlant(ArmPlant):
    """Puts NaN into hand_y from t = 0.1 s on, only where q0_shoulder > 150 deg."""
    def step(self, t, h):
        super().step(t, h)
        if t >= 0.1 - 1e-9 and self.values["q0_shoulder"][0] > 150:
            self.values["hand_y"] = np.full(self.batch_size, np.nan)

class RaisingArmPlant(ArmPlant):
    """Raises from t = 0.1 s on, naming the file its ArmPlant came from."""
    def step(self, t, h):
        if t >= 0.1 - 1e-9:
            raise RuntimeError("gear stripped in " + ArmPlant.step.__code__.co_filename)
        super().step(t, h)
'''


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    """Every FMU the tests use, built once: the two variants and two broken plants."""
    folder = tmp_path_factory.mktemp("fmus")
    plants = folder / "rhi_test_broken_plants.py"
    plants.write_text(BROKEN_PLANTS)
    built = {variant: build_fmu(folder / f"{variant}.fmu", variant) for variant in ("native", "kinematic")}
    for plant in ("NanArmPlant", "RaisingArmPlant"):
        built[plant] = build_fmu(folder / f"{plant}.fmu", component=f"rhi_test_broken_plants:{plant}",
                                 model_name=plant, extra_files=[plants])
    return built


def run(body, held, u_shoulder=0.5, u_elbow=0.0, stop=0.6, batch_size=1, parameters=()):
    """The same master code for every body: constant commands into the body, all outputs recorded."""
    system = System([Constant("shoulder", unit="deg/s"), Constant("elbow", unit="deg/s"), body],
                    [("shoulder.y", "body.u_shoulder"), ("elbow.y", "body.u_elbow")])
    result = simulate(system, stop, 0.02, batch_size=batch_size, record=[f"body.{o}" for o in OUTPUTS],
                      parameters={"shoulder.value": u_shoulder, "elbow.value": u_elbow, "body.held": held,
                                  **dict(parameters)})
    return {o: result.values[f"body.{o}"] for o in OUTPUTS}


def under_fmpy(path, held, stop=0.6):
    """The FMU alone under fmpy.simulate_fmu, an independent master."""
    unzipdir = extracted(str(path))
    guard_library(unzipdir, read_model_description(str(path)).coSimulation.modelIdentifier)
    saved = list(sys.path)
    try:
        result = simulate_fmu(unzipdir, stop_time=stop, step_size=0.02, output_interval=0.02,
                              start_values={"u_shoulder": 0.5, "held": held}, output=list(OUTPUTS))
    finally:
        sys.path[:] = saved  # a pythonfmu FMU prepends its resources to sys.path
    return result


def test_exported_fmu_is_valid_and_declares_the_contract(fmus):
    for variant in ("native", "kinematic"):
        assert validate_fmu(str(fmus[variant])) == []
        assert check_contract(fmus[variant], BODY_CONTRACT) == []
    native, adapter = ArmPlant(), FMUComponent(fmus["native"], "body", BODY_CONTRACT)
    for name, variable in native.variables.items():
        mirrored = adapter.variables[name]
        assert (mirrored.causality, mirrored.type, mirrored.description, mirrored.min, mirrored.max) == \
            (variable.causality, variable.type, variable.description, variable.min, variable.max)
        assert mirrored.unit == (variable.unit if variable.type == "Real" else "")  # FMI 2.0: units on Real
        if variable.causality in ("parameter", "input"):
            assert mirrored.start == variable.start  # exactly: 17 significant digits in the XML
        if variable.causality == "output":
            assert mirrored.depends_on == ()  # state outputs: no algebraic loop through the body
    names = zipfile.ZipFile(fmus["native"]).namelist()
    assert "resources/components/body/plant.py" in names and not any(n.endswith(".pyc") for n in names)


@pytest.mark.parametrize("held", [False, True])
def test_fmu_under_fmpy_reproduces_the_native_plant(fmus, held):
    alone = under_fmpy(fmus["native"], held)
    native = run(ArmPlant(), held)
    assert len(alone) == 31 and np.allclose(alone["time"], np.arange(31) * 0.02, atol=1e-12)
    for name in OUTPUTS:
        np.testing.assert_allclose(alone[name], native[name][:, 0], rtol=0, atol=1e-9)
    moved = native["q_shoulder"][-1, 0] - REST_POSE[0]
    if held:  # clamped: the hand stays put and pushes
        assert abs(moved) < 0.01 and np.hypot(native["force_x"][-1, 0], native["force_y"][-1, 0]) > 0.1
    else:  # free: 0.5 deg/s for 0.6 s, less the servo lag
        assert 0.28 < moved < 0.3 and native["force_x"][-1, 0] == 0


def test_adapter_through_the_master_matches_the_native_plant_per_trial(fmus):
    trials = dict(held=np.array([False, True, True]), u_shoulder=np.array([0.5, 0.5, -1.0]),
                  u_elbow=np.array([0.0, 0.3, 1.0]), batch_size=3,
                  parameters={"body.q0_elbow": [-91.0, -95.0, -80.0]})
    native, adapted = run(ArmPlant(), **trials), run(FMUComponent(fmus["native"], "body", BODY_CONTRACT), **trials)
    for name in OUTPUTS:
        np.testing.assert_allclose(adapted[name], native[name], rtol=0, atol=1e-9)
    assert np.allclose(adapted["q_elbow"][0], [-91.0, -95.0, -80.0], atol=1e-12)  # parameters reached the FMUs


def test_kinematic_variant_differs_only_where_the_physics_differs(fmus):
    kinematic_free, native_free = run(FMUComponent(fmus["kinematic"], "body", BODY_CONTRACT), False), run(ArmPlant(), False)
    times = np.arange(31) * 0.02
    np.testing.assert_allclose(kinematic_free["q_shoulder"][:, 0], REST_POSE[0] + 0.5 * times, atol=1e-12)
    lag = kinematic_free["q_shoulder"][-1, 0] - native_free["q_shoulder"][-1, 0]
    assert 0.001 < lag < 0.02  # the servo's lag behind the command (deg), nothing else
    assert np.allclose(kinematic_free["hand_x"], native_free["hand_x"], atol=2e-4)
    kinematic_held, native_held = run(FMUComponent(fmus["kinematic"], "body", BODY_CONTRACT), True), run(ArmPlant(), True)
    force = np.array([kinematic_held["force_x"][-1, 0], kinematic_held["force_y"][-1, 0]])
    assert np.allclose(force, [native_held["force_x"][-1, 0], native_held["force_y"][-1, 0]], rtol=2e-3)
    assert kinematic_held["hand_x"][-1, 0] == pytest.approx(-0.30, abs=1e-12)
    # Statics by virtual work: J^T F = tau = K * u, J by central differences of forward kinematics.
    pose, step = np.array(REST_POSE), 1e-6
    columns = [(np.array(forward(*np.add(pose, d))) - np.array(forward(*np.subtract(pose, d)))) / (2 * np.radians(step))
               for d in np.eye(2) * step]
    gain = ArmPlant().variables["servo_gain"].start
    np.testing.assert_allclose(np.array(columns) @ force, [gain * np.radians(0.5), 0.0], atol=1e-7)


def break_fmu(source, target, drop=(), edit=lambda xml: xml):
    """Copy an FMU, leaving out files that start with any of ``drop`` and editing its XML."""
    with zipfile.ZipFile(source) as old, zipfile.ZipFile(target, "w") as new:
        for item in old.infolist():
            if not any(item.filename.startswith(prefix) for prefix in drop):
                data = old.read(item)
                new.writestr(item, edit(data.decode()).encode() if item.filename == "modelDescription.xml" else data)
    return target


CO_SIMULATION = '<CoSimulation needsExecutionTool'
BROKEN = {
    "not a zip": (dict(), "not a zip archive"),
    "no description": (dict(drop=("modelDescription.xml",)), "has no modelDescription.xml"),
    "FMI 3.0": (dict(edit=lambda x: x.replace('fmiVersion="2.0"', 'fmiVersion="3.0"')), "FMI version '3.0'"),
    "FMI 1.0": (dict(edit=lambda x: x.replace('fmiVersion="2.0"', 'fmiVersion="1.0"')), "FMI version '1.0'"),
    "model exchange": (dict(edit=lambda x: x.replace(CO_SIMULATION, '<ModelExchange needsExecutionTool')),
                       "model exchange only"),
    "no binaries": (dict(drop=("binaries/",)), "no binary for this platform (binaries/linux64/ArmBody.so"),
    "renamed": (dict(edit=lambda x: x.replace('name="hand_x"', 'name="hand_left"')), "missing variable hand_x"),
    "causality": (dict(edit=lambda x: x.replace('causality="input"', 'causality="parameter"', 1)),
                  "u_shoulder has causality parameter, the contract needs input"),
    "type": (dict(edit=lambda x: x.replace('<Boolean start="true"/>', '<Integer start="1"/>')),
             "held has type Integer, the contract needs Boolean"),
    "unit": (dict(edit=lambda x: x.replace('unit="N"/>', 'unit="kN"/>', 1)),
             "force_x has unit 'kN', the contract needs 'N'"),
}


@pytest.mark.parametrize("case", BROKEN)
def test_each_contract_error_is_named(fmus, tmp_path, case):
    how, expected = BROKEN[case]
    path = tmp_path / "Broken.fmu"
    if case == "not a zip":
        path.write_text("this is not an FMU\n")
    else:
        break_fmu(fmus["native"], path, **how)
    problems = check_contract(path, BODY_CONTRACT)
    assert len(problems) == 1 and expected in problems[0], problems
    with pytest.raises(ComponentError, match="body: Broken.fmu cannot be used"):
        FMUComponent(path, "body", BODY_CONTRACT)


def test_every_problem_is_reported_at_once(fmus, tmp_path):
    cases = ("FMI 3.0", "model exchange", "renamed", "causality", "type", "unit")

    def edit_all(xml):
        for case in cases:
            xml = BROKEN[case][0]["edit"](xml)
        return xml

    path = break_fmu(fmus["native"], tmp_path / "Wreck.fmu", drop=("binaries/",), edit=edit_all)
    with pytest.raises(ComponentError) as caught:
        FMUComponent(path, "body", BODY_CONTRACT)
    message = str(caught.value)
    assert "(7 problems)" in message and "\n" not in message
    for case in cases:
        assert BROKEN[case][1] in message
    assert "no binary for this platform (binaries/linux64/ArmBody.so" in message


def test_nan_output_stops_the_run_naming_fmu_time_variable_and_trial(fmus):
    with pytest.raises(SimulationError, match=r"body failed the step at t = 0\.1 s \(error\): FMU 'NanArmPlant' "
                                              r"\(NanArmPlant\.fmu\): output hand_y is nan in trial 1 at t = 0\.12 s"
                       ) as caught:
        run(FMUComponent(fmus["NanArmPlant"], "body", BODY_CONTRACT), True, batch_size=3,
            parameters={"body.q0_shoulder": [147.0, 150.5, 147.5]})
    assert caught.value.trials == (1,)  # only that trial is blamed: the experiment drops it and goes on


def test_a_raising_fmu_stops_the_run_with_its_reason_and_runs_its_own_code(fmus):
    with pytest.raises(SimulationError, match=r"t = 0\.1 s \(discard\): FMU 'RaisingArmPlant' .*fmi2DoStep returned "
                                              r"discard in trial 0 at t = 0\.1 s \(RuntimeError: gear stripped in "
                                              r"(\S+)\)") as caught:
        run(FMUComponent(fmus["RaisingArmPlant"], "body", BODY_CONTRACT), False)
    # Even in this process, which imported the checkout's plant, the FMU ran the copy it carries.
    plant_file = str(caught.value).rsplit("gear stripped in ", 1)[1].rstrip(")")
    assert plant_file.endswith("resources/components/body/plant.py") and plant_file != sys.modules[
        "rhi.components.body.plant"].__file__ == ArmPlant.step.__code__.co_filename


def test_fmu_runs_without_this_checkout(fmus, tmp_path):
    """A fresh Python that cannot import this checkout's packages runs the FMU (on its own copy)."""
    script = textwrap.dedent(f"""
        import os, sys
        sys.meta_path = [f for f in sys.meta_path if not getattr(f, "__module__", "").startswith("__editable__")]
        sys.path = [p for p in sys.path if "__editable__" not in p and p not in ("", {os.getcwd()!r})]
        try:
            import rhi
            raise SystemExit("the checkout is still importable")
        except ImportError:
            pass
        from fmpy import simulate_fmu
        result = simulate_fmu({str(fmus["native"])!r}, stop_time=0.2, step_size=0.02, output_interval=0.02,
                              start_values={{"u_shoulder": 0.5, "held": False}}, output=["q_shoulder"])
        print(repr(float(result["q_shoulder"][-1])), flush=True)
        os._exit(0)  # pythonfmu 0.7 may crash at interpreter exit (see rhi.components.fmu.library)
        """)
    done = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True,
                          timeout=60, env={k: v for k, v in os.environ.items() if k != "PYTHONPATH"})
    assert done.returncode == 0, done.stderr
    assert float(done.stdout) == pytest.approx(run(ArmPlant(), False, stop=0.2)["q_shoulder"][-1, 0], abs=1e-12)


def test_export_command(tmp_path, capsys):
    assert run_export(Namespace(variant=None, out=str(tmp_path / "Body.fmu"))) == 0
    assert "variant native" in capsys.readouterr().out and check_contract(tmp_path / "Body.fmu", BODY_CONTRACT) == []
    with pytest.raises(ConfigError, match="--variant 'springy' is not one of native, kinematic"):
        run_export(Namespace(variant="springy", out=str(tmp_path / "B.fmu")))
    with pytest.raises(ConfigError, match="--out .*must be a file name ending in .fmu"):
        run_export(Namespace(variant="native", out=str(tmp_path / "Body.zip")))


def test_a_swapped_body_gets_the_body_keys_it_declares_and_the_rest_are_named(fmus):
    """The kinematic FMU meets the body contract but has no substeps, masses or load cell: the experiment runs
    it with the keys it declares (held, servo gain, torque limit: its held force is the statics of those)."""
    from rhi.master.tasks import illusion as experiment
    from rhi.master import config as configuration
    from rhi.master.config.sources import undeclared
    from tests.test_batching import tiny_config, tiny_model

    config = configuration.merge(tiny_config(steps=20), {"body": {"servo_gain": 10.0}})
    trials = experiment.plan(config)[:2]
    body = FMUComponent(fmus["kinematic"], "body", BODY_CONTRACT)
    system = experiment.build_system(Decoder(tiny_model(), threads=1), config, body)
    assert undeclared(experiment.parameters(trials, config), system) == [
        "body.substeps", "body.upper_arm_mass", "body.forearm_mass", "body.clamp_stiffness", "body.clamp_damping",
        "body.release_time"]
    result = experiment.run_batch(Decoder(tiny_model(), threads=1), trials, config,
                                  FMUComponent(fmus["kinematic"], "body", BODY_CONTRACT))
    u = np.radians(np.stack([result.values["brain.u_shoulder"][-1], result.values["brain.u_elbow"][-1]], 1))
    force = np.stack([result.values["body.force_x"][-1], result.values["body.force_y"][-1]], 1)
    assert np.abs(u).min() > 0  # the brain acts, so the force below is a real check
    # The configured gain reached the FMU: its held force is the statics of K = 10, J^T F = K u.
    per_radian = jacobian(*REST_POSE) * 180 / np.pi
    np.testing.assert_allclose(force @ per_radian, 10.0 * u, rtol=1e-9, atol=1e-12)
