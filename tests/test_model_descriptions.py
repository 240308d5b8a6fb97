"""Every component of the project describes itself as a schema-valid FMI 2.0 modelDescription.xml, and says what
this file writes down by hand: value references, causality, variability, types, units and their SI definitions,
start values and ranges, output dependencies, and the array ports FMI 2.0 cannot carry (docs/design.md, the body
contract). The XML is read back with fmpy (and ElementTree for the vendor annotation), never compared with the
variable list it was generated from."""
import math
from xml.etree import ElementTree

import pytest
from fmpy import read_model_description

from rhi.components.body.camera import Camera
from rhi.components.body.plant import ArmPlant
from rhi.components.body.rubber_arm import RubberArm
from rhi.components.brain.integrator import Brain
from rhi.components.stimulus import Stimulus

CONTRACT = {"u_shoulder": ("input", "deg/s"), "u_elbow": ("input", "deg/s"), "q_shoulder": ("output", "deg"),
            "q_elbow": ("output", "deg"), "hand_x": ("output", "m"), "hand_y": ("output", "m"),
            "force_x": ("output", "N"), "force_y": ("output", "N"), "q0_shoulder": ("parameter", "deg"),
            "q0_elbow": ("parameter", "deg")}

# The scalar variables of each component, in value-reference order (0, 1, ...), as this file knows them.
SCALARS = {
    ArmPlant: ["u_shoulder", "u_elbow", "q_shoulder", "q_elbow", "hand_x", "hand_y", "force_x", "force_y", "held",
               "q0_shoulder", "q0_elbow", "substeps", "servo_gain", "torque_limit", "upper_arm_mass", "forearm_mass",
               "clamp_stiffness", "clamp_damping", "release_time"],
    Camera: ["resolution", "blur", "ball_radius", "arm_visible"],
    RubberArm: ["offset_x", "offset_y"],
    Stimulus: ["period", "delay_min", "delay_max", "seed", "ball_distance", "stop_time", "visual_time", "tactile_time",
               "stroke_duration", "touch", "arm_in_view", "arm_visible"],
    Brain: ["proprioceptive_variance", "gamma0", "sync_sd", "async_density", "decay_rate", "action_limit",
            "spatial_sd", "action_time_constant", "q_shoulder", "q_elbow", "visual_error", "visual_stiffness",
            "goal_error", "goal_stiffness", "hand_x", "hand_y", "visual_time", "tactile_time", "u_shoulder", "u_elbow", "gamma", "free_energy"],
}
# Array ports (name: causality, shape, dependsOn or None for a non-output), in the vendor annotation.
ARRAYS = {
    ArmPlant: {},
    Camera: {"arm_pose": ("input", "2", None), "ball": ("input", "2", None),
             "image": ("output", "64 64", "arm_pose ball")},
    RubberArm: {"pose": ("output", "2", ""), "hand": ("output", "2", "")},
    Stimulus: {"target": ("input", "2", None), "ball": ("output", "2", "target"),
               "blocks": ("parameter", "1 2", None), "hidden": ("parameter", "1 2", None)},  # rows: Stimulus(blocks=1)
    Brain: {"mu0": ("parameter", "2", None), "visual_drive": ("input", "2", None), "goal_drive": ("input", "2", None),
            "seen_hand": ("input", "2", None),
            "mu": ("output", "2", ""),
            "action_rate": ("output", "2", "")},
}


def described(component, folder):
    path = folder / "modelDescription.xml"
    path.write_text(component.model_description())
    return read_model_description(str(path), validate=True), ElementTree.parse(path).getroot()


@pytest.mark.parametrize("make", list(SCALARS), ids=lambda make: make.__name__)
def test_model_description_validates_with_the_known_variables(make, tmp_path):
    component = make(resolution=64) if make is Camera else make()
    description, root = described(component, tmp_path)
    assert (description.fmiVersion, description.modelName) == ("2.0", make.__name__)
    assert description.coSimulation.modelIdentifier == component.name
    references = {v.name: v.valueReference for v in description.modelVariables}
    assert references == {name: index for index, name in enumerate(SCALARS[make])}
    for variable in description.modelVariables:
        assert variable.variability == ("fixed" if variable.causality == "parameter" else
                                        "discrete" if variable.type != "Real" else "continuous"), variable.name
    arrays = {a.get("name"): (a.get("causality"), a.get("shape"), a.get("dependsOn"))
              for a in root.iterfind("VendorAnnotations/Tool[@name='rhi']/Arrays/Array")}
    assert arrays == ARRAYS[make]


def test_native_body_meets_the_fmu_contract_as_written_here(tmp_path):
    description, _ = described(ArmPlant(), tmp_path)
    variables = {v.name: v for v in description.modelVariables}
    for name, (causality, unit) in CONTRACT.items():
        assert (variables[name].causality, variables[name].type, variables[name].unit) == (causality, "Real", unit)
    assert variables["held"].type == "Boolean" and variables["held"].causality == "parameter"
    assert variables["held"].start == "true" and variables["held"].initial == "exact"
    assert (variables["substeps"].type, variables["substeps"].start, variables["substeps"].min,
            variables["substeps"].max) == ("Integer", "20", "1", "10000")
    # The rest pose of docs/design.md (hand at (-0.30, 0.50) m, elbow outward), to the digits the XML carries.
    assert float(variables["q0_shoulder"].start) == pytest.approx(147.71944544231397, abs=1e-12)
    assert float(variables["q0_elbow"].start) == pytest.approx(-91.22898516948906, abs=1e-12)
    assert (variables["q0_elbow"].min, variables["q0_elbow"].max) == ("-180.0", "0.0")
    assert (variables["servo_gain"].start, variables["servo_gain"].unit) == ("20.0", "N.m.s/rad")
    assert (variables["clamp_stiffness"].start, variables["clamp_stiffness"].unit) == ("20000.0", "N/m")
    for name in ("u_shoulder", "u_elbow"):
        assert variables[name].start == "0.0"
    for name in ("q_shoulder", "q_elbow", "hand_x", "hand_y", "force_x", "force_y"):
        assert (variables[name].initial, variables[name].start) == ("calculated", None), name
    # Every output is a state of the plant: no direct feedthrough from the commands (the master needs no loop).
    assert [(o.variable.name, o.dependencies) for o in description.outputs] == [
        (name, []) for name in ("q_shoulder", "q_elbow", "hand_x", "hand_y", "force_x", "force_y")]
    assert [u.variable.name for u in description.initialUnknowns] == [o.variable.name for o in description.outputs]
    # The units in SI: degrees are radians times pi/180, a newton is kg m s^-2.
    units = {u.name: u.baseUnit for u in description.unitDefinitions}
    assert (units["deg"].rad, units["deg"].factor) == (1, pytest.approx(math.pi / 180, rel=1e-15))
    assert (units["deg/s"].rad, units["deg/s"].s, units["deg/s"].factor) == (1, -1, pytest.approx(math.pi / 180))
    assert (units["N"].kg, units["N"].m, units["N"].s, units["N"].factor) == (1, 1, -2, 1.0)
    assert (units["N.m.s/rad"].kg, units["N.m.s/rad"].m, units["N.m.s/rad"].s, units["N.m.s/rad"].rad) == (1, 2, -1, -1)


def test_the_brain_describes_its_parameters_inputs_and_outputs(tmp_path):
    description, _ = described(Brain(), tmp_path)
    variables = {v.name: v for v in description.modelVariables}
    expected = {"proprioceptive_variance": ("parameter", "deg2", "1.0"), "gamma0": ("parameter", "1", "0.01"),
                "sync_sd": ("parameter", "s", "0.2"), "async_density": ("parameter", "1/s", "0.5"),
                "decay_rate": ("parameter", "1/s3", "0.0125"), "action_limit": ("parameter", "deg/s", "1.0"),
                "q_shoulder": ("input", "deg", "NaN"), "visual_time": ("input", "s", "-INF"),
                "u_shoulder": ("output", "deg/s", None), "gamma": ("output", "1", None)}
    for name, (causality, unit, start) in expected.items():
        assert (variables[name].causality, variables[name].unit, variables[name].start) == (causality, unit, start)
    assert (variables["gamma"].min, variables["gamma"].max) == ("0.0", "1.0")
    assert (variables["gamma0"].min, variables["gamma0"].max) == ("0.0", "1.0")
    # Outputs are the integrator's state after the step: no direct feedthrough from any scalar input.
    assert {o.variable.name: o.dependencies for o in description.outputs} == {
        "u_shoulder": [], "u_elbow": [], "gamma": [], "free_energy": []}
