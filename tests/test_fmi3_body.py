"""The C body built for FMI 3.0 from the same source as its FMI 2.0 twin: valid under two checkers (fmpy's and
fmutool's), declaring the twin's ports as Float64 arrays, and computing the twin's numbers bit for bit under FMPy -
the truth here is the FMI 2.0 build, which tests/test_c_body.py holds against the Python kinematic arm."""
import math
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi3 import FMU3Slave
from fmpy.validation import validate_fmu

from rhi.components.body.variants import KinematicArm
from rhi.components.fmi_export.description_fmi3 import to_xml3
from rhi.master.export.c_body import ARRAYS, build_c_fmu

FMUTOOL = Path(sys.executable).with_name("fmutool")  # fmu-manipulation-toolbox, in the test extra
# The FMI 2.0 outputs, in the order the FMI 3.0 arrays q, hand, force carry them.
OUTPUTS = ("q_shoulder", "q_elbow", "hand_x", "hand_y", "force_x", "force_y")
# Parameters off their starts, and a torque limit the commands below exceed (tau = K u pi/180 up to 3.5 N m),
# so that the clip is taken as well as the plain statics.
PARAMETERS = {"q0_shoulder": 120.0, "q0_elbow": -70.0, "servo_gain": 5.0, "torque_limit": 2.0}


@pytest.fixture(scope="module")
def twins(tmp_path_factory):
    """The C body built once for each FMI version."""
    folder = tmp_path_factory.mktemp("fmi3_body")
    return {fmi: build_c_fmu(folder / f"KinematicC{fmi[0]}.fmu", fmi=fmi) for fmi in ("2.0", "3.0")}


def commands(t):
    """A command that varies within the run (deg/s): both joints, both signs."""
    return [40.0 * math.sin(2 * math.pi * 1.3 * t), -25.0 * math.cos(2 * math.pi * 0.7 * t)]


def drive(path, held, folder, steps=80, h=0.0125):
    """The FMU stepped by hand through fmpy with commands(t): one row of the six outputs per communication point
    (the FMI 3.0 arrays flattened in declaration order), and the FMI 3.0 time after each step (else None)."""
    description = read_model_description(str(path))
    reference = {v.name: v.valueReference for v in description.modelVariables}
    fmi3 = description.fmiVersion == "3.0"
    slave = (FMU3Slave if fmi3 else FMU2Slave)(guid=description.guid, unzipDirectory=extract(str(path), folder),
                                               modelIdentifier=description.coSimulation.modelIdentifier,
                                               instanceName="body")
    names = list(PARAMETERS) + (["u"] if fmi3 else ["u_shoulder", "u_elbow"])
    outputs = [reference[n] for n in (("q", "hand", "force") if fmi3 else OUTPUTS)]
    set_reals, get_reals = (slave.setFloat64, lambda: slave.getFloat64(outputs, nValues=6)) if fmi3 else \
        (slave.setReal, lambda: slave.getReal(outputs))
    slave.instantiate()
    try:
        if not fmi3:
            slave.setupExperiment(startTime=0.0)
        slave.setBoolean([reference["held"]], [held])
        set_reals([reference[n] for n in names], [*PARAMETERS.values(), *commands(0.0)])
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        rows, times = [get_reals()], []
        for k in range(steps):
            t = k * h
            set_reals([reference[n] for n in names[len(PARAMETERS):]], commands(t))
            slave.doStep(t, h)
            rows.append(get_reals())
            if fmi3:
                times.append(slave.getFloat64([reference["time"]])[0])
        slave.terminate()
    finally:
        slave.freeInstance()
    return np.array(rows), (np.array(times) if fmi3 else None)


def test_the_fmi3_body_is_valid_and_declares_its_twins_ports_as_arrays(twins):
    assert validate_fmu(str(twins["3.0"])) == []
    two, three = (read_model_description(str(twins[fmi])) for fmi in ("2.0", "3.0"))
    assert (two.fmiVersion, three.fmiVersion) == ("2.0", "3.0")
    scalars = {v.name: v for v in two.modelVariables}
    variables = {v.name: v for v in three.modelVariables}
    assert variables.pop("time").causality == "independent"  # FMI 3.0 asks for exactly one
    carried = {n for _, members in ARRAYS.values() for n in members}
    assert set(variables) == set(ARRAYS) | (set(scalars) - carried)
    for name, variable in variables.items():
        members = [scalars[n] for n in ARRAYS[name][1]] if name in ARRAYS else [scalars[name]]
        assert [int(d.start) for d in variable.dimensions] == ([len(members)] if name in ARRAYS else [])
        assert variable.valueReference == members[0].valueReference  # one table of values serves both versions
        for member in members:
            assert (variable.causality, variable.variability, variable.initial, variable.unit,
                    variable.min, variable.max) == (member.causality, member.variability, member.initial,
                                                    member.unit, member.min, member.max), (name, member.name)
            assert variable.type == {"Real": "Float64"}.get(member.type, member.type)
        starts = [m.start for m in members]
        assert variable.start == (None if None in starts else " ".join(starts) if name in ARRAYS else starts[0])
    names = zipfile.ZipFile(twins["3.0"]).namelist()
    assert names == ["modelDescription.xml", "binaries/x86_64-linux/KinematicArmC.so"]  # FMI 3.0's folder names


@pytest.mark.skipif(not FMUTOOL.exists(), reason="fmutool is not installed (the test extra: fmu-manipulation-toolbox)")
@pytest.mark.parametrize("fmi", ["2.0", "3.0"])
def test_fmutool_finds_no_problem(twins, fmi):
    done = subprocess.run([str(FMUTOOL), "-input", str(twins[fmi]), "-check"], capture_output=True, text=True,
                          timeout=120)
    log = done.stdout + done.stderr
    assert done.returncode == 0 and "ERROR" not in log, log
    assert f"compliant with FMI-{fmi[0]}" in log and f"No semantic error against the FMI-{fmi[0]}" in log


@pytest.mark.parametrize("held", [False, True])
def test_by_hand_the_fmi3_body_is_its_fmi2_twin_to_the_last_bit(twins, held, tmp_path):
    two, _ = drive(twins["2.0"], held, tmp_path / "2")
    three, times = drive(twins["3.0"], held, tmp_path / "3")
    assert np.array_equal(three, two)
    assert times.tolist() == [k * 0.0125 + 0.0125 for k in range(80)]  # the independent variable: t + h, as summed
    if held:  # the statics of a command that turns around: the force changes, and not only its size
        assert np.ptp(two[:, 4]) > 1.0 and np.ptp(two[:, 5]) > 1.0 and np.all(two[:, :2] == two[0, :2])
    else:  # the joints follow the command: degrees of travel each way
        assert np.ptp(two[:, 0]) > 1.0 and np.ptp(two[:, 1]) > 1.0 and np.all(two[:, 4:] == 0.0)


@pytest.mark.parametrize("held", [False, True])
def test_under_fmpy_simulate_the_fmi3_body_is_its_fmi2_twin_to_the_last_bit(twins, held):
    run = dict(stop_time=0.5, step_size=0.01, output_interval=0.01)
    two = simulate_fmu(str(twins["2.0"]), **run, output=list(OUTPUTS),
                       start_values={**PARAMETERS, "held": held, "u_shoulder": 30.0, "u_elbow": -45.0})
    three = simulate_fmu(str(twins["3.0"]), **run, output=["q", "hand", "force"],
                         start_values={**PARAMETERS, "held": held, "u": [30.0, -45.0]})
    assert np.array_equal(three["time"], two["time"])
    flat = np.concatenate([three["q"], three["hand"], three["force"]], axis=1)
    assert np.array_equal(flat, np.stack([two[n] for n in OUTPUTS], axis=1))
    moved = np.ptp(flat[:, 4:] if held else flat[:, :2], axis=0)
    assert np.all(moved > 0.1)  # free: the angles move; held: the force rises from 0 at the first step


def test_the_fmi3_body_refuses_a_wrong_count_of_values(twins, tmp_path):
    description = read_model_description(str(twins["3.0"]))
    reference = {v.name: v.valueReference for v in description.modelVariables}
    slave = FMU3Slave(guid=description.guid, unzipDirectory=extract(str(twins["3.0"]), tmp_path),
                      modelIdentifier="KinematicArmC", instanceName="body")
    slave.instantiate()
    try:
        starts = {v.name: float(v.start) for v in description.modelVariables if v.name.startswith("q0_")}
        assert slave.getFloat64([reference["q"]], nValues=2) == [starts["q0_shoulder"], starts["q0_elbow"]]
        for call in (lambda: slave.getFloat64([reference["q"]], nValues=1),        # half an array
                     lambda: slave.setFloat64([reference["u"]], [1.0]),              # half an array
                     lambda: slave.setFloat64([reference["q"]], [1.0, 2.0]),         # an output
                     lambda: slave.getFloat64([reference["q"] + 1], nValues=1)):     # inside an array
            with pytest.raises(Exception, match="fmi3(Get|Set)Float64"):
                call()
    finally:
        slave.freeInstance()


def export(*args, cwd):
    return subprocess.run([sys.executable, "-m", "rhi", "export-body", *args], capture_output=True, text=True,
                          timeout=120, cwd=cwd)


def test_rhi_export_body_fmi_3(tmp_path):
    done = export("--variant", "kinematic-c", "--fmi", "3.0", "--out", "C3.fmu", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "FMI 3.0" in done.stdout and read_model_description(str(tmp_path / "C3.fmu")).fmiVersion == "3.0"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["C3.fmu"]  # written whole, nothing left beside it


@pytest.mark.parametrize("args, message", [  # every variant is built for FMI 3.0 (tests/test_fmi3_native_body.py)
    (["--variant", "kinematic-c", "--fmi", "1.0"], "--fmi '1.0' is not one of 2.0, 3.0"),
    (["--fmi", "3"], "--fmi '3' is not one of 2.0, 3.0"),
])
def test_a_version_a_variant_cannot_be_built_for_is_one_line_and_nothing_written(tmp_path, args, message):
    done = export(*args, "--out", "B.fmu", cwd=tmp_path)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and message in done.stderr, done.stderr
    assert "Traceback" not in done.stderr and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("members, says", [(("u_shoulder", "q_elbow"), "not consecutive"),
                                           (("u_elbow", "q_shoulder"), "differ in causality"),
                                           (("held", "q0_shoulder"), "differ in causality")])
def test_an_array_of_unlike_ports_is_refused(members, says):
    with pytest.raises(ValueError, match=says):
        to_xml3(KinematicArm(), {"bad": ("", members)})


def test_an_fmi3_body_where_an_fmi2_body_belongs_is_one_line_naming_the_version(twins):
    from rhi.components.fmu.contract import check_contract

    assert check_contract(str(twins["3.0"])) == ["FMI version '3.0', need 2.0 (export the body with --fmi 2.0)"]
