"""Work shared by the participants of a cohort's cell: the camera's one picture, the stimulus schedule, the pose
encoder's network. Each shared result against the same thing computed per trial (compared with ``==``: the
sharing only leaves out repeated work, so any difference is a bug)."""
import numpy as np

from rhi.components.body import kinematics
from rhi.components.body.camera import Camera, render
from rhi.components.vision import pose_encoder as pe
from rhi.components.vision.image_sharing import distinct
from rhi.master import config as configuration
from rhi.master.config.protocol import make_trial
from rhi.master.decoders.cache import decoder_component, ensure_checkpoints
from rhi.master.tasks import scene
from rhi.master.tasks.illusion import wiring
from tests.test_stimulus import run_stimulus

POSE, BALL = (140.0, -80.0), (-0.3, 0.62)


def camera_image(poses, balls, visible=None):
    camera = Camera(resolution=16)
    camera.instantiate(len(poses))
    camera.set("arm_pose", np.array(poses, float))
    camera.set("ball", np.array(balls, float))
    if visible is not None:
        camera.set("arm_visible", np.array(visible))
    camera.enter_initialization_mode()
    camera.exit_initialization_mode()
    return camera.get("image")


def test_one_picture_for_the_whole_batch_is_drawn_once_and_broadcast():
    image = camera_image([POSE] * 5, [BALL] * 5)
    assert image.strides[0] == 0 and not image.flags.writeable  # one drawing, every trial a view of it
    assert np.array_equal(image, render(np.array([POSE] * 5), 16, np.array([BALL] * 5)))
    first, inverse = distinct(image)
    assert first.tolist() == [0] and inverse.tolist() == [0] * 5
    # two pictures, or an arm out of view: every trial its own row, as before
    for image in (camera_image([POSE, POSE, kinematics.REST_POSE], [BALL] * 3),
                  camera_image([POSE] * 3, [BALL] * 3, visible=[True, False, True])):
        assert image.strides[0] != 0 and image.flags.writeable


def test_the_schedule_computed_once_per_distinct_schedule_gives_each_trial_its_own_outputs():
    # Four trials, two schedules (every 2 s throughout; every 1 s in a block from 3 to 7 s, stopping at 6 s)
    one_block, blocks = np.array([[0.0, np.inf]]), np.array([[3.0, 7.0]])  # a stimulus of one block row
    trials = {"period": [2.0, 1.0, 2.0, 1.0], "stop_time": [np.inf, 6.0, np.inf, 6.0], "seed": [4, 5, 6, 7],
              "delay_max": [0.1, 1.0, 1.0, 0.1], "blocks": [one_block, blocks, one_block, blocks]}
    together = run_stimulus(9.0, 4, **{name: np.array(value) for name, value in trials.items()})
    for trial in range(4):
        alone = run_stimulus(9.0, 1, **{name: np.array(value[trial:trial + 1]) for name, value in trials.items()})
        for output, values in alone.items():
            assert np.array_equal(together[output][:, trial], values[:, 0]), (trial, output)


def test_a_cell_of_participants_shares_the_pose_encoder_and_gets_the_unshared_bits(monkeypatch):
    config = configuration.load(model_name="ownership", overrides={"experiment.steps": 8,
                                                                    "experiment.decoders": ["conv"]})
    checkpoints, _ = ensure_checkpoints(config, progress=False)
    trials = [make_trial(config, "conv", "left", "sync", index) for index in range(6)]
    plain, made, results = scene.pose_encoders, [], []
    for share in (True, False):
        def factory(config, kind, threads, share=share):
            def build_one(name):
                component = plain(config, kind, threads)(name)
                component.share = share
                made.append(component)
                return component
            return build_one
        monkeypatch.setattr(scene, "pose_encoders", factory)
        pe.STORE.clear()
        decoder = decoder_component("conv", checkpoints["conv"], config, True, 1)
        results.append(wiring.run_batch(decoder, trials, config))
    shared, unshared = made
    assert shared.sharing and not unshared.sharing
    assert shared.evaluated <= 9  # one picture a step (the initial one and 8 steps), not six
    for path, values in results[0].values.items():
        assert np.array_equal(values, results[1].values[path], equal_nan=True), path
