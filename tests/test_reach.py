"""The reach task: the free arm reaches a seen goal; goals, the goal image, refusals and the measures by hand."""
import csv
import json
import os

import numpy as np
import pytest

from rhi.components.body import camera, kinematics
from rhi.components.body.arm_pose import PosedArm
from rhi.components.body.camera import Camera
from rhi.components.body.plant import ArmPlant
from rhi.components.brain.goal import GoalAttractor, GoalOnset, body_space_attraction, body_space_goal_error
from rhi.components.brain.integrator import Brain
from linear_decoder import LinearDecoder
from rhi.master.commands.cli import main
from rhi.master.cosim import ConfigError, System, simulate
from rhi.master.tasks.reach import task as reach


def test_goals_follow_the_released_agents_law_and_do_not_depend_on_the_count():
    """|offset| in [low, high) per joint with both signs; the same seed the same goals; 3 goals are the first
    3 of 5; both decoders get the same goals."""
    few = reach.plan(reach.load(overrides={"reach.goals": 3}))
    many = reach.plan(reach.load(overrides={"reach.goals": 5}))
    assert [t for t in few if t.decoder == "conv" and t.band == "far"] == \
        [t for t in many if t.decoder == "conv" and t.band == "far"][:3]
    conv = [(t.band, t.shoulder_offset, t.elbow_offset) for t in many if t.decoder == "conv"]
    assert conv == [(t.band, t.shoulder_offset, t.elbow_offset) for t in many if t.decoder == "vae"]
    offsets = {band: np.array([o[1:] for o in conv if o[0] == band]) for band in ("near", "far")}
    for band, (low, high) in (("near", (1.0, 8.0)), ("far", (8.0, 18.0))):
        assert np.all((np.abs(offsets[band]) >= low) & (np.abs(offsets[band]) < high))
    signs = np.sign(np.concatenate(list(offsets.values())))
    assert (signs > 0).any() and (signs < 0).any()


def test_a_goal_out_of_the_joint_ranges_is_refused_with_one_line(tmp_path, capsys):
    """A band reaching past the decoders' training range (shoulder rest +- 40 deg): exit 2, one line, no DIR."""
    (tmp_path / "bad.toml").write_text("[reach.ranges]\nfar = [8.0, 45.0]\n")
    status = main(["reach", "--config", str(tmp_path / "bad.toml"), "--out", str(tmp_path / "out")])
    lines = capsys.readouterr().err.splitlines()
    assert status == 2 and len(lines) == 1
    assert lines[0].startswith("rhi reach: error: reach.ranges.far = [8.0, 45.0]") and "rest ± 40 deg" in lines[0]
    assert not (tmp_path / "out").exists()
    with pytest.raises(ConfigError, match="reach.bands: unknown band 'middle'"):
        reach.load(overrides={"reach.bands": ["middle"]})
    (tmp_path / "band.toml").write_text("[reach]\nbands = ['mid']\n[reach.ranges]\nmid = [2.0, 3.0]\n")
    assert {t.band for t in reach.plan(reach.load(tmp_path / "band.toml"))} == {"mid"}  # a band of one's own


def test_time_to_reach_and_path_length_by_hand():
    times = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    distance = np.array([[5.0, 5.0, 5.0], [0.5, 2.0, 3.0], [2.0, 0.5, 3.0], [0.9, 0.5, 0.5], [0.8, 0.2, 2.0]])
    # trial 0 enters at 1 s, leaves, stays in from 3 s; trial 1 stays in from 2 s; trial 2 ends outside
    assert np.array_equal(reach.time_to_reach(times, distance, 1.0), [3.0, 2.0, np.nan], equal_nan=True)
    x, y = np.array([[0.0], [0.03], [0.03]]), np.array([[0.0], [0.04], [0.0]])
    assert reach.path_length_cm(x, y)[0] == pytest.approx(5.0 + 4.0, rel=1e-12)  # a 3-4-5 step, then 4 cm


def test_the_body_space_attraction_is_minus_the_gradient_of_its_free_energy():
    """Central differences of 1/2 w sum (x_g - mu)^2 / Sigma_g (a quadratic: exact up to rounding, 1e-9)."""
    mu, goal = np.array([[150.0, -90.0]]), np.array([[158.0, -101.0]])
    variance, ratio = np.array([[1.5, 4.0]]), np.array([2.0])
    drive = body_space_attraction(mu, goal, variance, ratio)
    assert drive == pytest.approx(np.array([[2.0 * 8.0 / 1.5, 2.0 * -11.0 / 4.0]]), rel=1e-15)
    for joint in range(2):
        step = np.zeros((1, 2))
        step[0, joint] = 1e-3
        slope = (body_space_goal_error(mu + step, goal, variance, ratio)
                 - body_space_goal_error(mu - step, goal, variance, ratio)) / 2e-3
        assert -slope[0] == pytest.approx(drive[0, joint], abs=1e-9)
    attractor = GoalAttractor()
    attractor.instantiate(1)
    for name, value in (("mu", mu), ("goal_pose", goal), ("goal_pose_variance", variance)):
        attractor.set(name, value)
    attractor.setup_experiment()
    attractor.enter_initialization_mode()
    attractor.exit_initialization_mode()
    assert np.array_equal(attractor.values["goal_drive"], drive)
    assert attractor.values["goal_stiffness"][0] == 2.0 / 1.5


def test_the_free_arm_reaches_the_goal_of_a_linear_attractor():
    """The real pymunk arm, free, under the paper's brain and action law, pulled by an attractor image whose
    decoder is linear (g = A mu + b, A^T A = k I per joint): the belief's fixed point is the goal, and the loop
    (mu, s_p, a) is linear, lambda^3 + (1+k) lambda^2 + lambda + k per joint (Sigma_p = 1), stable by
    Routh-Hurwitz. After 60 s the slowest mode has decayed by exp(Re(lambda) 60 s); the bound allows the
    whole 4-deg offset times 4 that factor (the clipped start) plus 0.01 deg (the servo's lag)."""
    k, pixels = 2.0, 2
    A = np.sqrt(k) * np.eye(pixels)[:, :2]
    goal = np.array(kinematics.REST_POSE) + np.array([3.0, -4.0])
    b = np.zeros(pixels)
    parts = [LinearDecoder(A, b, A @ goal, name="goal_decoder"), Brain(), ArmPlant()]
    links = [("brain.mu", "goal_decoder.mu"), ("goal_decoder.visual_drive", "brain.goal_drive"),
             ("goal_decoder.visual_error", "brain.goal_error"), ("goal_decoder.visual_stiffness", "brain.goal_stiffness"),
             ("body.q_shoulder", "brain.q_shoulder"), ("body.q_elbow", "brain.q_elbow"),
             ("brain.u_shoulder", "body.u_shoulder"), ("brain.u_elbow", "body.u_elbow")]
    result = simulate(System(parts, links), stop_time=60.0, step_size=0.02, parameters={
        "brain.mu0": np.array(kinematics.REST_POSE), "brain.action_time_constant": np.inf, "body.held": False},
        record=["body.q_shoulder", "body.q_elbow"])
    final = np.array([result.values["body.q_shoulder"][-1, 0], result.values["body.q_elbow"][-1, 0]])
    slowest = max(np.roots([1.0, 1.0 + k, 1.0, k]).real)
    assert slowest < 0
    assert np.all(np.abs(final - goal) < 4 * 4.0 * np.exp(slowest * 60.0) + 0.01), final - goal


@pytest.fixture(scope="module")
def tiny_reach(quick_cache, tmp_path_factory):
    """`rhi reach --quick` (tiny decoders at 32 px, 2 near goals, 500 steps) into a folder, in this process."""
    os.environ["RHI_CACHE"] = str(quick_cache)
    out = tmp_path_factory.mktemp("reach") / "out"
    try:
        assert main(["reach", "--quick", "--out", str(out)]) == 0
    finally:
        del os.environ["RHI_CACHE"]
    return out


def read(path):
    with open(path, newline="") as file:
        return list(csv.DictReader(file))


def test_the_free_arm_reaches_on_a_tiny_decoder_end_to_end(tiny_reach):
    """Every file; the start distance is the rest hand to the goal hand by the forward kinematics; the path is
    at least the straight line between its ends; the arm moved toward its goal."""
    summary, goals = read(tiny_reach / "summary.csv"), read(tiny_reach / "goals.csv")
    assert [(row["decoder"], row["band"], row["n_goals"]) for row in summary] == [("conv", "near", "2"),
                                                                                  ("vae", "near", "2")]
    run = json.loads((tiny_reach / "run.json").read_text())
    assert run["command"] == "rhi reach" and run["attractor"] == "pixels"
    assert sorted(run["figures"]) == ["error_over_time.png", "paths.png", "success_vs_distance.png"]
    rest = np.array(kinematics.forward(*kinematics.REST_POSE))
    for row in goals:
        goal = np.array(kinematics.forward(kinematics.REST_POSE[0] + float(row["goal_shoulder_offset_deg"]),
                                           kinematics.REST_POSE[1] + float(row["goal_elbow_offset_deg"])))
        assert float(row["start_distance_cm"]) == pytest.approx(100 * np.hypot(*(goal - rest)), rel=1e-5)
        assert float(row["path_length_cm"]) >= abs(float(row["start_distance_cm"]) - float(row["final_distance_cm"]))
        assert float(row["final_distance_cm"]) < float(row["start_distance_cm"])
    steps = read(tiny_reach / "trials.csv")
    assert len(steps) == 4 * (500 // 25 + 1)


def test_the_goal_image_is_the_cameras_picture_of_the_goal_pose(quick_cache):
    """The goal camera's image, in the reach system, has the bytes of the camera's render of the goal pose."""
    from rhi.master.decoders.cache import checkpoint_path

    config = reach.load(quick=True)
    trials = reach.plan(config)[:2]
    os.environ["RHI_CACHE"] = str(quick_cache)
    try:
        path = checkpoint_path("conv", config, must_exist=True)
    finally:
        del os.environ["RHI_CACHE"]
    system = reach.build_system("conv", path, config)
    result = simulate(system, stop_time=0.02, step_size=0.02, batch_size=2,
                      parameters=reach.parameters(trials, config, system), record=["goal_camera.image", "goal.hand"])
    poses = np.array([t.goal_pose for t in trials])
    expected = camera.render(poses, config["experiment"]["resolution"], None, blur=config["camera"]["blur"])
    assert result.values["goal_camera.image"][-1].tobytes() == expected.tobytes()
    assert np.array_equal(result.values["goal.hand"][0], np.stack(kinematics.forward(poses[:, 0], poses[:, 1]), 1))
    alone = simulate(System([PosedArm(), Camera("goal_camera", resolution=32)], [("goal.pose", "goal_camera.arm_pose")]),
                     stop_time=0.02, step_size=0.02, parameters={"goal.shoulder": 150.0, "goal.elbow": -80.0},
                     record=["goal_camera.image"])
    assert alone.values["goal_camera.image"][0, 0].tobytes() == camera.render([[150.0, -80.0]], 32)[0].tobytes()


def test_a_held_arm_let_go_moves_freely_from_its_release_time():
    """Held to 0.2 s (the hand still, a force on the load cell), then free: no force, and the shoulder turns at
    the commanded 1 deg/s (the servo reaches the speed within a few ms: K / inertia ~ 100/s)."""
    body = ArmPlant()
    body.instantiate(1)
    body.set("release_time", 0.2)
    body.setup_experiment()
    body.enter_initialization_mode()
    body.exit_initialization_mode()
    q, force = [body.values["q_shoulder"][0]], [0.0]
    for k in range(50):
        body.set("u_shoulder", 1.0)
        body.do_step(0.02 * k, 0.02)
        q.append(body.values["q_shoulder"][0])
        force.append(float(np.hypot(body.values["force_x"][0], body.values["force_y"][0])))
    q, force = np.array(q), np.array(force)
    # held: the hand moves only by force / stiffness, 0.1 mm at 2 N, about 0.016 deg over a 0.36 m limb
    assert abs(q[10] - q[0]) < 0.05 and force[10] > 0.1
    assert np.all(force[11:] == 0.0)
    assert (q[-1] - q[20]) / 0.6 == pytest.approx(1.0, rel=0.02)  # free, at the commanded speed


def test_a_goal_that_appears_pulls_only_from_its_onset():
    onset = GoalOnset()
    onset.instantiate(2)
    onset.set("onset", np.array([0.5, 0.0]))
    onset.set("drive", np.array([[1.0, -2.0], [3.0, 4.0]]))
    onset.setup_experiment()
    onset.enter_initialization_mode()
    onset.exit_initialization_mode()
    assert onset.values["goal_drive"].tolist() == [[0.0, 0.0], [3.0, 4.0]]
    onset.do_step(0.5, 0.02)
    assert onset.values["goal_drive"].tolist() == [[1.0, -2.0], [3.0, 4.0]]
