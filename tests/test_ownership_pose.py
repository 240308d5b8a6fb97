"""The ownership model's own pose encoders (master/decoders/pose_encoders.py, OWNERSHIP_BOX): found by default and
overridden by a given file, a box that holds the rubber arm over the arm's whole reach, and a reading of the rubber
arm at 60 cm, where the decoders' encoders saturate.

Truth: the arm's inverse kinematics (:func:`rhi.components.body.kinematics.inverse`) and the camera's image of the
rubber arm there (:func:`rhi.components.body.camera.render`, the ball on its path)."""
import numpy as np
import pytest

from rhi.components.body import camera, kinematics
from rhi.components.vision import pose_encoder as pe
from rhi.master import config as configuration
from rhi.master.config.protocol import HALF_RANGES, rubber_pose
from rhi.master.cosim import ConfigError
from rhi.master.decoders import pose_encoders
from rhi.master.decoders.cache import SHIPPED, pose_encoder_path
from rhi.master.decoders.training import train_settings

KINDS = ("conv", "vae")
FAR = 0.60  # m, the farthest rubber hand of the distance study, shoulder at rest - 88.5 deg


def test_the_ownership_model_reads_its_own_shipped_pose_encoders_unless_given_one(tmp_path):
    ownership, causal = configuration.load(model_name="ownership"), configuration.load(model_name="causal")
    for kind in KINDS:
        assert pose_encoder_path(kind, ownership) == str(SHIPPED / f"pose-ownership-{kind}-r64.pt")
        assert pose_encoder_path(kind, causal) == str(SHIPPED / f"pose-{kind}-r64.pt")  # "" as before
    given = tmp_path / "mine.pt"
    given.write_bytes((SHIPPED / "pose-conv-r64.pt").read_bytes())
    config = configuration.load(overrides={"ownership.conv_pose_encoder": str(given)}, model_name="ownership")
    assert pose_encoder_path("conv", config) == str(given)
    assert pose_encoder_path("vae", config) == str(SHIPPED / "pose-ownership-vae-r64.pt")
    at_32 = configuration.load(overrides={"experiment.resolution": 32}, model_name="ownership")
    with pytest.raises(ConfigError, match="no shipped conv pose encoder at 32 px for the ownership model.*"
                                          "ownership.conv_pose_encoder"):
        pose_encoder_path("conv", at_32)


def test_the_box_holds_the_rubber_arm_over_its_reach_and_the_real_arms_range_at_the_shipped_density():
    low, high = np.array(pose_encoders.OWNERSHIP_BOX).T
    assert np.array(pose_encoders.OWNERSHIP_CENTRE) == pytest.approx((low + high) / 2)
    assert np.array(pose_encoders.OWNERSHIP_HALF_RANGES) == pytest.approx((high - low) / 2)
    # the rubber hand along y = REST_HAND's y, out to where the hand is at the arm's full length from the shoulder
    reach = np.sqrt((kinematics.UPPER_ARM + kinematics.FOREARM) ** 2 - kinematics.REST_HAND[1] ** 2)
    x = kinematics.SHOULDER[0] + np.linspace(-reach, reach, 4001) * (1 - 1e-9)
    poses = np.stack(kinematics.inverse(x, np.full_like(x, kinematics.REST_HAND[1])), axis=1)
    assert x[0] - kinematics.REST_HAND[0] < -0.42 and x[-1] - kinematics.REST_HAND[0] > 0.62
    assert np.all(poses >= low + 5.0) and np.all(poses <= high - 5.0)  # the stated margin
    real = np.array([np.subtract(kinematics.REST_POSE, HALF_RANGES), np.add(kinematics.REST_POSE, HALF_RANGES)])
    assert np.all(real >= low) and np.all(real <= high)
    shipped = train_settings(configuration.load()).samples / np.prod(2 * np.array(HALF_RANGES))
    assert pose_encoders.OWNERSHIP_SAMPLES / np.prod(high - low) >= shipped


@pytest.fixture(scope="module")
def far_images():
    """The rubber arm at FAR with the ball at 5 points of its path, as the camera draws it: truth (2,), images.
    (There the hand, and so the ball, is beyond the field of view: the upper arm and most of the forearm show.)"""
    truth = np.array(rubber_pose(FAR))
    hand = np.array([kinematics.REST_HAND[0] + FAR, kinematics.REST_HAND[1]])
    balls = hand + np.stack([np.zeros(5), np.linspace(0.0, pose_encoders.BALL_REACH, 5)], axis=1)
    return truth, camera.render(np.repeat(truth[None], 5, axis=0), 64, balls)


@pytest.mark.parametrize("kind", KINDS)
def test_the_ownership_pose_encoders_read_the_rubber_arm_at_60_cm(kind, far_images):
    model = pe.load_encoder(SHIPPED / f"pose-ownership-{kind}-r64.pt")
    assert model.rest_pose == pytest.approx(pose_encoders.OWNERSHIP_CENTRE, abs=0)
    assert model.half_ranges == pytest.approx(pose_encoders.OWNERSHIP_HALF_RANGES, abs=0)
    assert model.metadata["box_deg"] == [list(joint) for joint in pose_encoders.OWNERSHIP_BOX]
    truth, images = far_images
    angles, variance = model(images)
    # Calibrated over the box (variance scale on held-out poses): |error| <= 3 sd holds 99.7 % of a calibrated
    # Gaussian's errors; and the sd is no wider than 3x the box's rms error, so the bound is not a loose one.
    sd = np.sqrt(variance)
    assert np.all(np.abs(angles - truth) <= 3.0 * sd)
    assert np.all(sd <= 3.0 * np.array(model.metadata["rms_error_deg"]))
    # the test's power: the decoders' encoder of the slot saturates at its box's edge, rest - 40 deg (~108)
    shipped, _ = pe.load_encoder(SHIPPED / f"pose-{kind}-r64.pt")(images)
    assert np.all(shipped[:, 0] - truth[0] > 30.0)
