"""The moving rubber hand's parts by hand: the movement, the delayed mirror, the turning points; refusals."""
import numpy as np
import pytest

from rhi.components.body import kinematics
from rhi.components.body.movement import MirroredArm, Movement, periodic_step_velocity
from rhi.components.brain.turning_points import TurningPoints, turned
from rhi.master.cosim import ConfigError, System, simulate
from rhi.master.tasks import moving_hand


def test_the_step_velocity_lands_on_the_sine_at_every_step():
    """Summed over steps, the mean velocities give A sin(2 pi t / T) exactly (a telescoping sum, to rounding)."""
    h, steps = 0.02, 400
    amplitude, period = np.array([5.0]), np.array([4.0])
    position = np.cumsum([periodic_step_velocity(k * h, h, amplitude, period)[0] * h for k in range(steps)])
    times = h * np.arange(1, steps + 1)
    assert position == pytest.approx(5.0 * np.sin(2 * np.pi * times / 4.0), abs=1e-12)


def test_the_mirror_shows_the_real_arm_a_delay_later_and_the_turning_points_are_that_delay_apart():
    """The movement drives a stand-in body (its angle the integral of the command); the mirror, 0.3 s behind,
    turns 0.3 s after it; the first turning point of the sine is at T/4 = 1 s."""
    parts = [Movement(), MirroredArm(step_size=0.02), TurningPoints(), Integrator()]
    links = [("movement.u_shoulder", "body.u_shoulder"), ("body.q_shoulder", "rubber_arm.q_shoulder"),
             ("body.q_elbow", "rubber_arm.q_elbow"), ("rubber_arm.pose", "turning_points.seen_pose"),
             ("body.q_shoulder", "turning_points.q_shoulder")]
    result = simulate(System(parts, links), stop_time=2.0, step_size=0.02, parameters={"rubber_arm.delay": 0.3},
                      record=["body.q_shoulder", "rubber_arm.pose", "turning_points.visual_time",
                              "turning_points.tactile_time"])
    real = result.values["body.q_shoulder"][:, 0] - kinematics.REST_POSE[0]
    seen = result.values["rubber_arm.pose"][:, 0, 0] - kinematics.REST_POSE[0]
    # the mirror's step from t shows the body as sensed at t (its outputs of the step before) 0.3 s earlier:
    # recorded after the step (row t + h), 0.3 s + one step behind the body's row
    assert seen[16:] == pytest.approx(real[:-16], abs=1e-12) and np.all(seen[:16] == 0.0)
    felt, shown = result.values["turning_points.tactile_time"][-1, 0], result.values["turning_points.visual_time"][-1, 0]
    assert felt == pytest.approx(1.0, abs=0.021) and shown - felt == pytest.approx(0.3, abs=1e-9)


def test_a_reversal_needs_a_direction_first():
    turn, direction = turned(np.array([0.0, 1.0, 1.0, -1.0]), np.array([-1.0, 0.5, -0.5, 1e-12]))
    assert turn.tolist() == [False, False, True, False] and direction.tolist() == [-1.0, 1.0, -1.0, -1.0]


def test_bad_delays_are_refused(tmp_path):
    (tmp_path / "bad.toml").write_text("[moving_hand]\ndelays = [0.0, 0.25, 0.03]\n")
    with pytest.raises(ConfigError, match="whole number of 0.02 s steps"):
        moving_hand.load(tmp_path / "bad.toml")
    assert moving_hand.load(None, "causal")["model"]["name"] == "causal"  # any registered model runs it
    assert moving_hand.load()["moving_hand"]["period"] == 4.0


class Integrator:
    """A stand-in body: q_shoulder integrates u_shoulder exactly (a perfect servo), the elbow at rest."""

    def __new__(cls):
        from rhi.components.component import Component
        from rhi.components.variables import Variable

        class Body(Component):
            def __init__(self):
                super().__init__("body", [
                    Variable("u_shoulder", "input", start=0.0, unit="deg/s", description="command"),
                    Variable("q_shoulder", "output", start=kinematics.REST_POSE[0], unit="deg", depends_on=(),
                             description="angle"),
                    Variable("q_elbow", "output", start=kinematics.REST_POSE[1], unit="deg", depends_on=(),
                             description="angle")])

            def step(self, t, h):
                self.values["q_shoulder"] = self.values["q_shoulder"] + h * self.values["u_shoulder"]

        return Body()
