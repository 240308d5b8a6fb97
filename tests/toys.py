"""Small components with known analytic behaviour, for testing the master."""
import math

import numpy as np

from rhi.components.component import Component, StepFailure, Status
from rhi.components.variables import Variable


class Constant(Component):
    """Outputs a constant ``value``."""

    def __init__(self, name="source", unit="1"):
        super().__init__(name, [
            Variable("value", "parameter", start=1.0, unit=unit, description="the constant"),
            Variable("y", "output", unit=unit, description="equals value", depends_on=()),
        ])

    def initialize(self):
        self.values["y"] = self.values["value"].copy()

    def step(self, t, h):
        self.values["y"] = self.values["value"].copy()


class FirstOrder(Component):
    """dx/dt = -rate * x + gain * u, integrated exactly with u held over the step (zero-order hold).

    With rate = 0 it is an integrator. The output is the state: no direct feedthrough.
    """

    def __init__(self, name="plant", unit="1", input_start=0.0):
        super().__init__(name, [
            Variable("rate", "parameter", start=0.0, unit="1/s", min=0.0, description="decay rate"),
            Variable("gain", "parameter", start=1.0, unit="1/s", description="input gain"),
            Variable("x0", "parameter", start=0.0, unit=unit, description="initial state"),
            Variable("u", "input", start=input_start, unit=unit, description="input"),
            Variable("x", "output", unit=unit, description="state", depends_on=()),
        ])

    def initialize(self):
        self.values["x"] = self.values["x0"].copy()

    def step(self, t, h):
        rate, gain, u, x = (self.values[k] for k in ("rate", "gain", "u", "x"))
        decay = np.exp(-rate * h)
        # (1 - e^{-rate h}) / rate, with its limit h at rate = 0
        weight = np.where(rate > 0, -np.expm1(-rate * h) / np.where(rate > 0, rate, 1.0), h)
        self.values["x"] = decay * x + gain * weight * u


class Gain(Component):
    """y = k * u, direct feedthrough."""

    def __init__(self, name="gain"):
        super().__init__(name, [
            Variable("k", "parameter", start=2.0, unit="1", description="gain"),
            Variable("u", "input", start=0.0, unit="1", description="signal in"),
            Variable("y", "output", unit="1", description="k * u"),
        ])

    def initialize(self):
        self.step(0.0, 0.0)

    def step(self, t, h):
        self.values["y"] = self.values["k"] * self.values["u"]


class FailsAt(Component):
    """Fails its step at ``fail_time`` with the given status."""

    def __init__(self, name="fragile", fail_time=0.5, status=Status.DISCARD):
        super().__init__(name, [Variable("y", "output", description="time", depends_on=())])
        self.fail_time, self.status = fail_time, status
        self.terminated = False

    def step(self, t, h):
        if t >= self.fail_time - 1e-12:
            raise StepFailure("the toy was told to fail here", self.status)
        self.values["y"] = np.full(self.batch_size, t + h)

    def terminate_hook(self):
        self.terminated = True


class Image(Component):
    """Outputs a float32 image port."""

    def __init__(self, name="camera", size=8, element="float32"):
        super().__init__(name, [Variable("image", "output", "Array", shape=(size, size), element=element,
                                         start=None, unit="1", description="an image")])

    def initialize(self):
        self.values["image"] = np.zeros((self.batch_size, *self.variables["image"].shape), np.float32)

    def step(self, t, h):
        self.values["image"] = np.full_like(self.values["image"], math.sin(t))


class ImageSink(Component):
    """Takes an image input with no start value."""

    def __init__(self, name="decoder", size=8, element="float32"):
        super().__init__(name, [
            Variable("image", "input", "Array", shape=(size, size), element=element, start=None, unit="1",
                     description="an image"),
            Variable("mean", "output", unit="1", description="mean brightness"),
        ])

    def step(self, t, h):
        self.values["mean"] = self.values["image"].reshape(self.batch_size, -1).mean(axis=1)


def assert_reads_no_simulator_position(system, brain) -> None:
    """A brain that sees the arm through a pose encoder: nothing carries a position from the simulator into it.
    The body gives only the sensed joint angles (proprioception); the rubber arm reaches it only through the camera
    (the stimulus' event times carry no position); no input of the brain is in metres."""
    links = [(c.source, c.target) for c in system.connections]
    into_brain = {source for source, target in links if target.startswith("brain.")}
    assert not (into_brain & {"rubber_arm.hand", "body.hand_x", "body.hand_y", "stimulus.ball"})
    assert {source for source in into_brain if source.startswith("body.")} == {"body.q_shoulder", "body.q_elbow"}
    assert "pose_encoder.pose" in into_brain
    assert not any(source.startswith("rubber_arm.") and target.startswith("brain.") for source, target in links)
    assert not any(v.unit == "m" for v in brain.variables.values() if v.causality == "input")
