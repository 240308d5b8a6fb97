"""Every component of the project describes itself as a schema-valid FMI 2.0 modelDescription.xml."""
import pytest
from fmpy import read_model_description

from components.body.camera import Camera
from components.body.plant import ArmPlant
from components.body.rubber_arm import RubberArm
from components.brain.integrator import Brain
from components.stimulus import Stimulus

CONTRACT = {"u_shoulder": ("input", "deg/s"), "u_elbow": ("input", "deg/s"), "q_shoulder": ("output", "deg"),
            "q_elbow": ("output", "deg"), "hand_x": ("output", "m"), "hand_y": ("output", "m"),
            "force_x": ("output", "N"), "force_y": ("output", "N"), "q0_shoulder": ("parameter", "deg"),
            "q0_elbow": ("parameter", "deg")}


@pytest.mark.parametrize("make", [ArmPlant, Camera, RubberArm, Stimulus, Brain])
def test_model_description_validates(make, tmp_path):
    component = make()
    path = tmp_path / "modelDescription.xml"
    path.write_text(component.model_description())
    description = read_model_description(str(path), validate=True)
    scalars = {v.name for v in description.modelVariables}
    assert scalars == {v.name for v in component.variables.values() if v.type != "Array"}


def test_native_body_meets_the_fmu_contract(tmp_path):
    path = tmp_path / "modelDescription.xml"
    path.write_text(ArmPlant().model_description())
    variables = {v.name: v for v in read_model_description(str(path)).modelVariables}
    for name, (causality, unit) in CONTRACT.items():
        assert (variables[name].causality, variables[name].type, variables[name].unit) == (causality, "Real", unit)
    assert variables["held"].type == "Boolean" and variables["held"].causality == "parameter"
