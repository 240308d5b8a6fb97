"""The pythonfmu bodies built for FMI 3.0 with pythonfmu3 (components/fmi_export/slave_fmi3.py): valid under two checkers
and the standard's table of ``initial``, declaring the C body's FMI 3.0 arrays over their FMI 2.0 twins' ports, and
computing the twins' numbers bit for bit, under FMPy and stepped by hand.

Truth: the FMI 2.0 pythonfmu FMU of the same variant (tests/test_fmu.py holds it against the native component);
for the layout, the C body's FMI 3.0 build (tests/test_fmi3_body.py).
"""
import importlib.util
import math
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi3 import FMU3Slave

from rhi.components.body.contract import FMI3_ARRAYS
from rhi.components.fmu import extracted, guard_library
from rhi.master.cosim import ConfigError
from rhi.master.export.body import check_fmi, export_body
from rhi.master.export.fmi_checks import CHECKS

pytestmark = pytest.mark.skipif(importlib.util.find_spec("pythonfmu3") is None,
                                reason="pythonfmu3 is not installed (the test extra: pip install pythonfmu3==0.3.4)")
VARIANTS = ("native", "kinematic")
OUTPUTS = ("q_shoulder", "q_elbow", "hand_x", "hand_y", "force_x", "force_y")  # as the arrays q, hand, force hold them
# Off their starts, where the variant has them: a torque limit the commands below exceed at times (the clip taken),
# fewer pymunk steps, and a held arm let go within the run (the load cell's release).
PARAMETERS = {"q0_shoulder": 120.0, "q0_elbow": -70.0, "servo_gain": 5.0, "torque_limit": 2.0, "substeps": 10,
              "release_time": 0.6}
STEPS, H = 80, 0.0125


@pytest.fixture(scope="module")
def bodies(tmp_path_factory):
    """{(variant, fmi): FMU} for both pythonfmu variants and versions, and the C body's FMI 3.0 build."""
    folder = tmp_path_factory.mktemp("fmi3_native_body")
    built = {(v, fmi): export_body(folder / f"{v}{fmi[0]}.fmu", v, fmi) for v in VARIANTS for fmi in ("2.0", "3.0")}
    built["kinematic-c", "3.0"] = export_body(folder / "c3.fmu", "kinematic-c", "3.0")
    return built


def slave(path, description):
    """FMPy's FMU2Slave or FMU3Slave of ``path``, unzipped once (a pythonfmu library held and released at exit)."""
    unzipped, identifier = extracted(str(path)), description.coSimulation.modelIdentifier
    if description.fmiVersion == "2.0":
        guard_library(unzipped, identifier)  # pythonfmu 0.7's heap at exit (components/fmu/library.py)
        return FMU2Slave(guid=description.guid, unzipDirectory=unzipped, modelIdentifier=identifier,
                         instanceName="body")
    return FMU3Slave(guid=description.guid, unzipDirectory=unzipped, modelIdentifier=identifier, instanceName="body")


def commands(t):
    """A command that varies within the run (deg/s): both joints, both signs."""
    return [40.0 * math.sin(2 * math.pi * 1.3 * t), -25.0 * math.cos(2 * math.pi * 0.7 * t)]


def drive(path, held):
    """The FMU stepped by hand with commands(t): a row of the six outputs per communication point (FMI 3.0's arrays
    flattened), and FMI 3.0's time after each step (else None)."""
    description = read_model_description(str(path))
    variables = {v.name: v for v in description.modelVariables}
    fmi3 = description.fmiVersion == "3.0"
    fmu = slave(path, description)
    ref = lambda names: [variables[n].valueReference for n in names]
    set_reals, set_ints = (fmu.setFloat64, fmu.setInt32) if fmi3 else (fmu.setReal, fmu.setInteger)
    inputs, outputs = (["u"], ["q", "hand", "force"]) if fmi3 else (["u_shoulder", "u_elbow"], list(OUTPUTS))
    get = (lambda: fmu.getFloat64(ref(outputs), nValues=6)) if fmi3 else (lambda: fmu.getReal(ref(outputs)))
    reals = {n: v for n, v in PARAMETERS.items() if n in variables and variables[n].type in ("Real", "Float64")}
    integers = {n: v for n, v in PARAMETERS.items() if n in variables and n not in reals}
    fmu.instantiate()
    try:
        fmu.setBoolean(ref(["held"]), [held])
        set_reals(ref(reals), list(reals.values()))
        if integers:
            set_ints(ref(integers), list(integers.values()))
        set_reals(ref(inputs), commands(0.0))
        if fmi3:
            fmu.enterInitializationMode(startTime=0.0)
        else:
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        rows, times = [get()], []
        for k in range(STEPS):
            set_reals(ref(inputs), commands(k * H))
            fmu.doStep(k * H, H)
            rows.append(get())
            if fmi3:
                times.append(fmu.getFloat64(ref(["time"]))[0])
        fmu.terminate()
    finally:
        fmu.freeInstance()
    return np.array(rows), (times if fmi3 else None)


@pytest.mark.parametrize("variant", VARIANTS)
def test_the_fmi3_body_passes_both_checkers_and_the_initial_table(bodies, variant):
    assert {name: check(bodies[variant, "3.0"]) for name, check in CHECKS.items()} == {name: [] for name in CHECKS}


@pytest.mark.parametrize("variant", VARIANTS)
def test_it_declares_its_twins_ports_as_the_c_bodys_arrays(bodies, variant):
    two, three, c = (read_model_description(str(bodies[key])) for key in
                     ((variant, "2.0"), (variant, "3.0"), ("kinematic-c", "3.0")))
    assert (three.fmiVersion, three.coSimulation.modelIdentifier) == ("3.0", two.coSimulation.modelIdentifier)
    scalars, variables = ({v.name: v for v in d.modelVariables} for d in (two, three))
    assert variables.pop("time").valueReference == len(scalars)  # FMI 3.0's independent variable, after the ports
    carried = {n for _, members in FMI3_ARRAYS.values() for n in members}
    assert set(variables) == set(FMI3_ARRAYS) | (set(scalars) - carried)
    for name, variable in variables.items():
        members = [scalars[n] for n in FMI3_ARRAYS[name][1]] if name in FMI3_ARRAYS else [scalars[name]]
        assert [int(d.start) for d in variable.dimensions] == ([len(members)] if name in FMI3_ARRAYS else [])
        assert variable.valueReference == members[0].valueReference  # one table of values serves both versions
        for member in members:
            assert (variable.causality, variable.variability, variable.initial, variable.unit, variable.min,
                    variable.max) == (member.causality, member.variability, member.initial, member.unit, member.min,
                                      member.max), (name, member.name)
            assert variable.type == {"Real": "Float64", "Integer": "Int32"}.get(member.type, member.type)
        starts = [m.start for m in members]
        assert variable.start == (None if None in starts else " ".join(starts) if name in FMI3_ARRAYS else starts[0])
    theirs = {v.name: v for v in c.modelVariables}
    for name in set(theirs) & set(variables):  # what both bodies have, declared alike (value references: arrays)
        mine = variables[name]
        assert (mine.type, [d.start for d in mine.dimensions], mine.causality, mine.variability, mine.initial,
                mine.unit, mine.description) == (theirs[name].type, [d.start for d in theirs[name].dimensions],
                                                 theirs[name].causality, theirs[name].variability,
                                                 theirs[name].initial, theirs[name].unit, theirs[name].description)
        assert name not in FMI3_ARRAYS or mine.valueReference == theirs[name].valueReference


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("held", [False, True])
def test_by_hand_the_fmi3_body_is_its_fmi2_twin_to_the_last_bit(bodies, variant, held):
    two, _ = drive(bodies[variant, "2.0"], held)
    three, times = drive(bodies[variant, "3.0"], held)
    assert np.array_equal(three, two)
    assert times == [k * H + H for k in range(STEPS)]  # the independent variable: t + h, as summed
    moved = np.ptp(two, axis=0)
    assert np.all(moved[:2] > 1.0) if not held or variant == "native" else np.all(moved[4:] > 1.0)
    if variant == "native" and held:  # the load cell let go at 0.6 s: a force before, none after
        assert np.any(two[: int(0.6 / H), 4:] != 0.0) and np.all(two[int(0.6 / H) + 2:, 4:] == 0.0)


@pytest.mark.parametrize("held", [False, True])
def test_under_fmpy_simulate_the_fmi3_body_is_its_fmi2_twin_to_the_last_bit(bodies, held):
    run = dict(stop_time=0.5, step_size=0.01, output_interval=0.01)
    given = {**PARAMETERS, "held": held}
    two = simulate_fmu(extracted(str(bodies["native", "2.0"])), **run, output=list(OUTPUTS),
                       start_values={**given, "u_shoulder": 30.0, "u_elbow": -45.0})
    three = simulate_fmu(extracted(str(bodies["native", "3.0"])), **run, output=["q", "hand", "force"],
                         start_values={**given, "u": [30.0, -45.0]})
    assert np.array_equal(three["time"], two["time"])
    flat = np.concatenate([three["q"], three["hand"], three["force"]], axis=1)
    assert np.array_equal(flat, np.stack([two[n] for n in OUTPUTS], axis=1))
    assert np.all(np.ptp(flat[:, 4:] if held else flat[:, :2], axis=0) > 0.1)  # free: the angles; held: the force


def test_a_set_of_half_an_array_or_more_is_refused(bodies, tmp_path):
    """In a process of its own: pythonfmu3 reports a slave's exception as fmi3Fatal, after which no call is safe."""
    code = textwrap.dedent(f"""
        from fmpy import extract, read_model_description
        from fmpy.fmi3 import FMU3Slave
        path = {str(bodies["native", "3.0"])!r}
        d = read_model_description(path)
        u = {{v.name: v.valueReference for v in d.modelVariables}}["u"]
        for values in ([1.0], [1.0, 2.0, 3.0]):
            fmu = FMU3Slave(guid=d.guid, unzipDirectory=extract(path, {str(tmp_path)!r} + str(len(values))),
                            modelIdentifier="ArmBody", instanceName="body")
            fmu.instantiate()
            try:
                fmu.setFloat64([u], values)
            except Exception as error:
                print(error)
            print(fmu.getFloat64([u], nValues=2))
    """)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    said = done.stdout.splitlines()  # with FMPy's log of what pythonfmu3 reports
    assert said.count("fmi3SetFloat64 failed with status 4 (fatal).") == 2
    assert said.count("[0.0, 0.0]") == 2  # u left at its start
    assert "1 values for 2 elements" in done.stdout and "3 values for 2 elements" in done.stdout


def test_rhi_export_body_fmi_3(tmp_path):
    done = subprocess.run([sys.executable, "-m", "rhi", "export-body", "--fmi", "3.0", "--out", "B3.fmu"],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "variant native, FMI 3.0" in done.stdout
    assert read_model_description(str(tmp_path / "B3.fmu")).fmiVersion == "3.0"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["B3.fmu"]  # written whole, nothing left beside it


def test_without_pythonfmu3_fmi_3_is_refused_in_one_line(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "pythonfmu3" else real(name, *a))
    with pytest.raises(ConfigError, match=r"^--fmi 3\.0 --variant native needs pythonfmu3 \(pip install"):
        check_fmi("native", "3.0")
    check_fmi("kinematic-c", "3.0")  # the C body needs no pythonfmu3
