"""The component model: lifecycle, get/set by name, step status, model description."""
import numpy as np
import pytest
from fmpy import read_model_description

from rhi.components.component import Component, ComponentError, Status
from rhi.components.variables import Variable
from tests.toys import FailsAt, FirstOrder, Gain, ImageSink


def ready(component, batch_size=1, **parameters):
    component.instantiate(batch_size)
    for name, value in parameters.items():
        component.set(name, value)
    component.setup_experiment(0.0, 1.0)
    component.enter_initialization_mode()
    component.exit_initialization_mode()
    return component


def test_lifecycle_runs_and_integrates():
    plant = ready(FirstOrder(), batch_size=3, gain=2.0, x0=[0.0, 1.0, 2.0])
    plant.set("u", 0.5)
    assert plant.do_step(0.0, 0.1) == Status.OK
    np.testing.assert_allclose(plant.get("x"), [0.1, 1.1, 2.1], rtol=0, atol=1e-15)
    plant.terminate()
    with pytest.raises(ComponentError, match="do_step needs the component step mode, but it is terminated"):
        plant.do_step(0.1, 0.1)


def test_parameters_only_before_initialization_ends():
    plant = ready(FirstOrder())
    with pytest.raises(ComponentError, match=r"plant\.gain is a parameter and can only be set before"):
        plant.set("gain", 3.0)


def test_unknown_variable_is_named():
    with pytest.raises(ComponentError, match=r"plant has no variable 'gian'"):
        ready(FirstOrder()).get("gian")


def test_outputs_cannot_be_set_and_types_are_checked():
    plant = FirstOrder()
    plant.instantiate(2)
    with pytest.raises(ComponentError, match=r"plant\.x is an output and cannot be set"):
        plant.set("x", 1.0)
    with pytest.raises(ComponentError, match=r"plant\.gain: 'fast' is not a Real"):
        plant.set("gain", "fast")
    with pytest.raises(ComponentError, match=r"plant\.rate = -1.0 is outside its range \[0.0, None\]"):
        plant.set("rate", -1.0)
    with pytest.raises(ComponentError, match=r"plant\.x0: .* per-trial shape \(\)"):
        plant.set("x0", [1.0, 2.0, 3.0])  # three values for a batch of two


def test_instantiate_rejects_bad_batch():
    with pytest.raises(ComponentError, match="batch_size must be a positive integer"):
        FirstOrder().instantiate(0)


def test_failed_step_reports_status_and_reason():
    toy = ready(FailsAt(fail_time=0.0, status=Status.DISCARD))
    assert toy.do_step(0.0, 0.1) == Status.DISCARD
    assert toy.last_reason == "the toy was told to fail here"


def test_variable_declarations_are_checked():
    with pytest.raises(ValueError, match="causality 'inputt'"):
        Variable("u", "inputt")
    with pytest.raises(ValueError, match="an Array needs a shape"):
        Variable("image", "input", "Array")
    with pytest.raises(ValueError, match="only outputs declare depends_on"):
        Variable("u", "input", depends_on=())


def test_model_description_is_valid_fmi2(tmp_path):
    """fmpy, an independent reader, validates the XML against the FMI 2.0 schema."""
    path = tmp_path / "modelDescription.xml"
    path.write_text(FirstOrder().model_description())
    description = read_model_description(str(path), validate=True)
    assert description.fmiVersion == "2.0"
    assert description.coSimulation.modelIdentifier == "plant"
    variables = {v.name: v for v in description.modelVariables}
    assert [v.name for v in description.modelVariables] == ["rate", "gain", "x0", "u", "x"]
    assert variables["gain"].causality == "parameter" and variables["gain"].start == "1.0"
    assert variables["u"].causality == "input" and variables["u"].unit == "1"
    assert variables["rate"].unit == "1/s"
    (output,) = description.outputs
    assert output.variable.name == "x" and output.dependencies == []  # state: no direct feedthrough
    units = {u.name: u for u in description.unitDefinitions}
    assert units["1/s"].baseUnit.s == -1


class Boundaries(Gain):
    def __init__(self):
        Component.__init__(self, "edges", [
            Variable("u", "input", start=float("nan"), description="not yet known"),
            Variable("t", "input", start=-float("inf"), unit="s", description="no event yet"),
            Variable("y", "output", description="out"),
        ])


def test_model_description_writes_nan_and_infinity_as_xml_schema_does(tmp_path):
    path = tmp_path / "modelDescription.xml"
    path.write_text(Boundaries().model_description())
    starts = {v.name: v.start for v in read_model_description(str(path)).modelVariables}
    assert starts == {"u": "NaN", "t": "-INF", "y": None}


def test_model_description_feedthrough_and_arrays(tmp_path):
    path = tmp_path / "modelDescription.xml"
    path.write_text(Gain().model_description())
    (output,) = read_model_description(str(path)).outputs
    assert [v.name for v in output.dependencies] == ["u"]  # undeclared = every input
    xml = ImageSink(size=4).model_description()
    assert '<Array name="image" causality="input" shape="4 4" element="float32"' in xml
    path.write_text(xml)
    assert [v.name for v in read_model_description(str(path)).modelVariables] == ["mean"]


class PublishesEarly(FirstOrder):
    """FirstOrder whose state is readable in initialization mode, from x0 alone."""

    def publish_initial(self):
        self.values["x"] = self.values["x0"].copy()


def test_initial_outputs_are_published_on_entering_initialization_mode():
    """publish_initial runs once the parameters are set, so the outputs are readable before initialization
    ends; the base hook publishes nothing (the output keeps its start value until initialize)."""
    early, plain = PublishesEarly(), FirstOrder()
    for component in (early, plain):
        component.instantiate(2)
        component.set("x0", [1.5, -2.0])
        component.setup_experiment(0.0, 1.0)
        component.enter_initialization_mode()
    np.testing.assert_array_equal(early.get("x"), [1.5, -2.0])
    np.testing.assert_array_equal(plain.get("x"), [0.0, 0.0])  # the start value
    for component in (early, plain):
        component.exit_initialization_mode()
        np.testing.assert_array_equal(component.get("x"), [1.5, -2.0])
