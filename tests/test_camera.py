"""The Pillow camera: determinism, smoothness under small pose changes, field of view, pictures.

The pictures in tests/pictures/ are the golden images: each test picture is written to a temporary folder and
compared with its golden twin, never written over it."""
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from rhi.components.body import camera
from rhi.components.body.camera import Camera, render
from rhi.components.body.kinematics import REST_HAND, REST_POSE, SHOULDER, UPPER_ARM, forward, inverse
from rhi.components.component import ComponentError

PICTURES = Path(__file__).parent / "pictures"
OFFSETS = {"left": -0.15, "center": 0.0, "right": 0.15}


def pixel_of(x, y, resolution):
    """(row, column) of the output pixel holding world point (x, y), computed from the field of view."""
    column = (x - camera.FIELD_X[0]) / (camera.FIELD_X[1] - camera.FIELD_X[0]) * resolution
    row = (camera.FIELD_Y[1] - y) / (camera.FIELD_Y[1] - camera.FIELD_Y[0]) * resolution
    return int(row), int(column)


def test_same_inputs_give_identical_bytes():
    poses = np.array([REST_POSE, (150.0, -80.0)])
    balls = np.array([[-0.3, 0.6], [np.nan, np.nan]])
    first, second = render(poses, 64, balls), render(poses.copy(), 64, balls.copy())
    assert first.dtype == np.float32 and first.shape == (2, 64, 64)
    assert first.tobytes() == second.tobytes()
    assert 0.0 <= first.min() and first.max() <= 1.0


@pytest.mark.parametrize("joint", [0, 1])
def test_a_tenth_of_a_degree_changes_the_image_less_than_a_degree(joint):
    step = np.zeros(2)
    step[joint] = 1.0
    rest = np.array([REST_POSE])
    base = render(rest, 64)
    small = np.abs(render(rest + 0.1 * step, 64) - base).mean()
    large = np.abs(render(rest + 1.0 * step, 64) - base).mean()
    assert 0 < small < large
    # Smooth, not a jump: a 0.1 degree change moves edges by about a tenth of what 1 degree does.
    assert small < 0.3 * large


def as_picture(image, path):
    """The 8-bit picture of a camera image, saved at ``path``; returns it as read back."""
    Image.fromarray(np.round(image * 255).astype(np.uint8)).save(path)
    return np.asarray(Image.open(path), dtype=np.int16)


def assert_like_golden(picture, name):
    """Within 3 of 255 gray levels everywhere, 0.2 on average, of tests/pictures/NAME (anti-aliasing may move
    with the Pillow version; a moved arm, ball or blur changes far more: the hand's disc alone spans 100+ levels)."""
    golden = np.asarray(Image.open(PICTURES / name), dtype=np.int16)
    assert golden.shape == picture.shape, name
    difference = np.abs(picture - golden)
    assert difference.max() <= 3 and difference.mean() <= 0.2, (name, difference.max(), difference.mean())


def test_each_condition_is_drawn_where_the_kinematics_put_it_and_looks_like_its_picture(tmp_path):
    resolution = 256
    for condition, offset in OFFSETS.items():
        hand = (REST_HAND[0] + offset, REST_HAND[1])
        ball = (hand[0], hand[1] + 0.12)  # the ball on its way down to the rubber hand
        image = render(np.array([inverse(*hand)]), resolution, np.array([ball]))[0]
        assert_like_golden(as_picture(image, tmp_path / f"camera_{condition}.png"), f"camera_{condition}.png")
        # Brightest pixel = the hand blob, at the hand's pixel; the ball is the distinct gray.
        brightest = np.unravel_index(np.argmax(image), image.shape)
        assert np.abs(np.subtract(brightest, pixel_of(*hand, resolution))).max() <= 2, condition
        assert image[pixel_of(*ball, resolution)] == pytest.approx(camera.BALL_LEVEL, abs=0.05)
    real = render(np.array([REST_POSE]), resolution, None)[0]
    assert_like_golden(as_picture(real, tmp_path / "camera_real_arm.png"), "camera_real_arm.png")
    # The middle of the forearm is limb-bright (not the hand's 1.0), the shoulder is inside the limb.
    shoulder = np.radians(REST_POSE[0])
    elbow = np.add(SHOULDER, UPPER_ARM * np.array([np.cos(shoulder), np.sin(shoulder)]))
    mid_forearm = (elbow + forward(*REST_POSE)) / 2
    assert real[pixel_of(*mid_forearm, resolution)] == pytest.approx(camera.LIMB_LEVEL, abs=0.05)
    assert real[pixel_of(-0.3, 0.62, resolution)] == 0  # no ball, and black background


def test_the_golden_pictures_tell_the_conditions_apart():
    """Guards the comparison above: the golden pictures differ from one another by far more than its tolerance."""
    pictures = [np.asarray(Image.open(PICTURES / f"camera_{c}.png"), dtype=np.int16) for c in OFFSETS]
    for first in range(3):
        for second in range(first + 1, 3):
            assert np.abs(pictures[first] - pictures[second]).max() > 100


def test_field_of_view_holds_every_condition_and_the_training_range_with_margin():
    corners = [(REST_POSE[0] + ds, REST_POSE[1] + de) for ds in (-40, 40) for de in (-50, 50)]
    rubber = [inverse(REST_HAND[0] + offset, REST_HAND[1]) for offset in OFFSETS.values()]
    images = render(np.array(corners + rubber), 64)
    border = np.concatenate([images[:, :2].ravel(), images[:, -2:].ravel(),
                             images[:, :, :2].ravel(), images[:, :, -2:].ravel()])
    assert border.max() < 1e-3
    assert (images.reshape(len(images), -1).max(axis=1) > 0.9).all()  # every hand is in view


def test_256_and_64_render_a_batch():
    """Sizes and batches only: speed is measured by `rhi bench`, not asserted here (a shared machine's wall clock)."""
    assert render(np.array([REST_POSE]), 256).shape == (1, 256, 256)
    poses = np.array(REST_POSE) + np.random.default_rng(0).uniform(-20, 20, (60, 2))
    images = render(poses, 64)
    assert images.shape == (60, 64, 64) and len({image.tobytes() for image in images}) == 60


def run_camera(poses_per_step, balls_per_step, resolution=32, **parameters):
    component = Camera(resolution=resolution)
    component.instantiate(len(poses_per_step[0]))
    for name, value in parameters.items():
        component.set(name, value)
    component.enter_initialization_mode()
    component.set("arm_pose", poses_per_step[0])
    component.set("ball", balls_per_step[0])
    component.exit_initialization_mode()
    images = [component.get("image")]
    for step, (poses, balls) in enumerate(zip(poses_per_step[1:], balls_per_step[1:])):
        component.set("arm_pose", poses)
        component.set("ball", balls)
        component.do_step(0.02 * step, 0.02)
        images.append(component.get("image"))
    return images


def test_component_with_its_cache_gives_the_same_bytes_as_render():
    # Trial 2 repeats trial 0 (pose and ball: drawn once, copied); trial 3 shares trial 0's pose
    # (and arm layer) with its own ball; trial 1 moves at step 2, so its layer must be redrawn.
    rubber, rest = inverse(-0.45, 0.5), np.array(REST_POSE)
    fixed = np.array([rubber, rest, rubber, rubber])
    moved = fixed + [[0.0, 0.0], [0.5, -0.5], [0.0, 0.0], [0.0, 0.0]]
    poses = [fixed, fixed, moved, moved]
    balls = [np.array([[-0.45, 0.7 - 0.05 * k], [np.nan, np.nan], [-0.45, 0.7 - 0.05 * k], [-0.40, 0.6]])
             for k in range(4)]
    images = run_camera(poses, balls)
    assert all(image.shape == (4, 32, 32) and image.dtype == np.float32 for image in images)
    for step in range(4):
        assert images[step].tobytes() == render(poses[step], 32, balls[step]).tobytes()
        assert not np.array_equal(images[step][0], images[step][3])  # same arm, other ball
    assert images[1] is not images[0]  # a new array each step, never mutated in place
    assert not np.array_equal(images[1][0], images[0][0])  # the ball moved


@pytest.mark.parametrize("resolution", [-64, 0, 4, 64.0, True])
def test_bad_resolution_is_one_clear_error(resolution):
    with pytest.raises(ComponentError, match="resolution"):
        render(np.array([REST_POSE]), resolution)
    with pytest.raises(ComponentError, match="resolution"):
        Camera(resolution=resolution)


def test_bad_poses_and_balls_name_the_argument():
    with pytest.raises(ComponentError, match="poses_deg"):
        render(np.array([[np.nan, 0.0]]), 64)
    with pytest.raises(ComponentError, match="balls"):
        render(np.array([REST_POSE]), 64, np.zeros((2, 2)))


def test_stimulus_rubber_arm_and_camera_run_together_under_the_master():
    from rhi.components.body.rubber_arm import RubberArm
    from rhi.components.stimulus import Stimulus
    from rhi.master import System, simulate
    system = System([Stimulus(), RubberArm(), Camera(resolution=32)],
                    [("rubber_arm.hand", "stimulus.target"), ("rubber_arm.pose", "camera.arm_pose"),
                     ("stimulus.ball", "camera.ball")])
    result = simulate(system, 2.0, 0.02, batch_size=2, parameters={"rubber_arm.offset_x": [-0.15, 0.15]},
                      record=["camera.image", "stimulus.ball", "rubber_arm.pose"])
    balls, poses, images = (result.values[k] for k in ("stimulus.ball", "rubber_arm.pose", "camera.image"))
    assert np.allclose(balls[-1], [[-0.45, 0.5], [-0.15, 0.5]])  # on the rubber hands at t = 2 s
    assert np.allclose(balls[0], [[-0.45, 0.75], [-0.15, 0.75]])  # the initial ball already follows the offset
    for tick in (0, 37, 100):
        assert images[tick].tobytes() == render(poses[tick], 32, balls[tick]).tobytes()


@pytest.mark.parametrize("ball", [(-0.3, 0.6), (camera.FIELD_X[0] + 0.01, 0.5), (0.1, camera.FIELD_Y[1] - 0.02)])
def test_the_ball_window_equals_drawing_and_blurring_the_whole_frame(ball):
    """The per-step shortcut (rasterise and blur only around the ball) against the plain full-frame way."""
    from PIL import ImageDraw
    resolution = 64
    factor = camera.supersampling(resolution)
    scale = resolution * factor
    canvas = Image.new("L", (scale, scale), 0)
    cx, cy = camera._to_canvas(ball[0], ball[1], scale)
    radius = camera.BALL_RADIUS / (camera.FIELD_X[1] - camera.FIELD_X[0]) * scale
    ImageDraw.Draw(canvas).ellipse([cx - radius, cy - radius, cx + radius, cy + radius], fill=255)
    full = camera._blur(camera._reduce(canvas, factor), resolution)
    rows, columns, patch = camera.ball_alpha(ball, resolution)
    windowed = np.zeros_like(full)
    windowed[rows, columns] = patch
    assert full.sum() > 1 and np.abs(windowed - full).max() < 1e-6


@pytest.mark.parametrize("shape, resolution, blur", [
    ((12, 12), 64, camera.BLUR_SIGMA), ((64, 64), 64, camera.BLUR_SIGMA), ((9, 17), 256, camera.BLUR_SIGMA),
    ((32, 32), 32, 0.04), ((16, 16), 64, 0.0)])
def test_blur_is_scipys_gaussian_filter_to_the_bit(shape, resolution, blur):
    """The camera's blur (weights made once, two correlate1d passes) against scipy's gaussian_filter itself."""
    from scipy.ndimage import gaussian_filter
    layer = np.random.default_rng(7).random(shape).astype(np.float32)
    sigma = blur / (camera.FIELD_X[1] - camera.FIELD_X[0]) * resolution
    expected = gaussian_filter(layer, sigma, mode="constant", truncate=3.0).astype(np.float32)
    got = camera._blur(layer, resolution, blur)
    assert got.dtype == np.float32 and got.tobytes() == expected.tobytes()


def test_blur_and_ball_radius_are_parameters_with_the_constants_as_defaults():
    poses = np.array([REST_POSE, inverse(-0.45, 0.5)])
    balls = np.array([[-0.3, 0.6], [-0.45, 0.55]])
    default = render(poses, 32, balls)
    assert render(poses, 32, balls, blur=camera.BLUR_SIGMA, ball_radius=camera.BALL_RADIUS).tobytes() == \
        default.tobytes()
    declared = Camera(resolution=32).variables
    assert (declared["blur"].start, declared["ball_radius"].start) == (camera.BLUR_SIGMA, camera.BALL_RADIUS)
    assert declared["blur"].unit == declared["ball_radius"].unit == "m"
    sharper, bigger = render(poses, 32, balls, blur=0.005), render(poses, 32, balls, ball_radius=0.06)
    assert not np.array_equal(sharper, default) and not np.array_equal(bigger, default)
    assert sharper.max() > default.max()  # less blur, brighter peaks (the hand's disc)
    area = lambda radius: camera.ball_alpha(balls[0], 32, ball_radius=radius)[2].sum()  # noqa: E731, in px
    assert area(0.06) / area(camera.BALL_RADIUS) == pytest.approx((0.06 / camera.BALL_RADIUS) ** 2, rel=0.05)
    again = render(poses.copy(), 32, balls.copy(), blur=0.005, ball_radius=0.06)
    assert again.tobytes() == render(poses, 32, balls, blur=0.005, ball_radius=0.06).tobytes()


def test_the_component_draws_with_its_blur_and_ball_radius():
    """Set before initialization, the parameters give render's bytes, the kept arm layers included."""
    rubber, rest = inverse(-0.45, 0.5), np.array(REST_POSE)
    poses = [np.array([rubber, rest])] * 3
    balls = [np.array([[-0.45, 0.7 - 0.05 * k], [-0.30, 0.6]]) for k in range(3)]
    images = run_camera(poses, balls, blur=0.025, ball_radius=0.05)
    for step in range(3):
        assert images[step].tobytes() == render(poses[step], 32, balls[step], blur=0.025, ball_radius=0.05).tobytes()
        assert images[step].tobytes() != render(poses[step], 32, balls[step]).tobytes()


def test_runs_after_the_first_reuse_the_kept_drawings_and_give_renders_bytes():
    """A second run of the same inputs draws nothing new and gives render's bytes (render draws afresh); a run with
    another blur or ball radius in between does not take the first run's drawings; kept drawings are read-only."""
    rubber, rest = inverse(-0.45, 0.5), np.array(REST_POSE)
    poses = [np.array([rubber, rest, rubber])] * 3
    balls = [np.array([[-0.45, 0.7 - 0.05 * k], [-0.30, 0.6], [np.nan, np.nan]]) for k in range(3)]
    expected = [render(poses[k], 32, balls[k]).tobytes() for k in range(3)]
    run_camera(poses, balls)
    drawn = camera.kept_ball_alpha.cache_info().misses, camera.kept_arm_layer.cache_info().misses
    other = run_camera(poses, balls, blur=0.031, ball_radius=0.021)
    again = run_camera(poses, balls)
    assert [image.tobytes() for image in again] == expected
    assert [image.tobytes() for image in other] == [render(poses[k], 32, balls[k], blur=0.031, ball_radius=0.021)
                                                      .tobytes() for k in range(3)]
    assert camera.kept_ball_alpha.cache_info().misses - drawn[0] == 5  # the other run: 3 + 1 ball places, a NaN
    assert camera.kept_arm_layer.cache_info().misses - drawn[1] == 2   # the other run's two poses
    layer = camera.kept_arm_layer(rest.tobytes(), 32, camera.BLUR_SIGMA)
    with pytest.raises(ValueError):
        layer[0, 0] = 1.0


@pytest.mark.parametrize("name", ["blur", "ball_radius"])
def test_per_trial_blur_or_ball_radius_is_refused_naming_it(name):
    poses, balls = [np.array([REST_POSE, REST_POSE])], [np.full((2, 2), np.nan)]
    with pytest.raises(ComponentError, match=rf"camera\.{name} = \[.*\] must be the same for every trial"):
        run_camera(poses, balls, **{name: [0.01, 0.02]})


@pytest.mark.parametrize("name, value", [("blur", -0.01), ("ball_radius", float("nan")), ("blur", "wide")])
def test_bad_blur_or_ball_radius_is_one_clear_error(name, value):
    with pytest.raises(ComponentError, match=name):
        render(np.array([REST_POSE]), 32, **{name: value})
