"""The pose encoder runs once per distinct image: the grouping is exact, and the shared computation gives the
unshared one's numbers bit for bit, in the component and in a causal model's lockstep batch of several
participants (compared with ``==``: no tolerance)."""
import numpy as np
import pytest
import torch

from rhi.components.body import kinematics
from rhi.components.body.camera import render
from rhi.components.vision import pose_encoder as pe
from rhi.components.vision.image_sharing import FeatureStore, distinct
from rhi.components.vision.networks import Encoder, preset
from rhi.master import config as configuration
from rhi.master.config import protocol
from rhi.master.tasks import scene
from rhi.master.tasks.illusion import wiring

RESOLUTION = 16
HALF_RANGES = (40.0, 50.0)


def tiny_pose_model(seed: int = 0) -> pe.PoseModel:
    torch.manual_seed(seed)
    return pe.PoseModel(Encoder(preset("tiny"), RESOLUTION), kinematics.REST_POSE, HALF_RANGES, (1.3, 0.7))


def images_with_repeats() -> np.ndarray:
    """12 images: 3 rubber-arm poses x 2 balls, each twice, interleaved (as a batch of participants shows them)."""
    poses = np.array([kinematics.REST_POSE, (140.0, -80.0), (155.0, -100.0)] * 4)
    balls = np.array([[np.nan, np.nan]] * 6 + [[-0.3, 0.6]] * 6)
    return render(poses, RESOLUTION, balls)


def test_distinct_groups_by_every_bit():
    images = images_with_repeats()
    first, inverse = distinct(images)
    by_bytes = {}
    expected = np.array([by_bytes.setdefault(image.tobytes(), b) for b, image in enumerate(images)])
    assert len(first) == 6 and np.array_equal(first[inverse], expected)
    # Images equal at every probed pixel but one elsewhere, and -0.0 against 0.0: different pictures.
    twins = np.zeros((4, RESOLUTION, RESOLUTION), np.float32)
    twins[1, 3, 5] = 1e-7
    twins[2, 3, 5] = -0.0
    first, inverse = distinct(twins)
    assert first.tolist() == [0, 1, 2] and inverse.tolist() == [0, 1, 2, 0]


def test_the_store_drops_the_least_recently_used_beyond_its_room():
    row = np.zeros(2**16, np.float32)  # 256 KiB each: a 1 MiB store holds four
    store = FeatureStore(1.0)
    for key in range(4):
        store.put((key,), row.copy())
    assert store.get((0,)) is not None  # 0 is now the most recent: 1 goes first
    store.put((4,), row.copy())
    assert store.get((1,)) is None and all(store.get((k,)) is not None for k in (0, 2, 3, 4))
    assert store.used == 4 * row.nbytes


def run_component(model, images_per_step, share: bool):
    component = pe.PoseEncoder(model, resolution=RESOLUTION, threads=1, share=share)
    component.instantiate(len(images_per_step[0]))
    component.setup_experiment(0.0)
    component.set("image", images_per_step[0])
    component.enter_initialization_mode()
    component.exit_initialization_mode()
    outputs = [(component.get("pose").copy(), component.get("pose_variance").copy())]
    for images in images_per_step[1:]:
        component.set("image", images)
        component.do_step(0.0, 0.02)
        outputs.append((component.get("pose").copy(), component.get("pose_variance").copy()))
    return component, outputs


def test_the_shared_encoder_gives_the_whole_batchs_bits():
    pe.STORE.clear()
    model = tiny_pose_model()
    images = images_with_repeats()
    moved = images.copy()
    moved[0] = render(np.array([(150.0, -95.0)]), RESOLUTION)[0]  # one new picture, alone: padded to MIN_ROWS
    steps = [images, images, moved]
    shared, with_sharing = run_component(model, steps, share=True)
    unshared, without = run_component(model, steps, share=False)
    assert shared.sharing and not unshared.sharing
    for (pose, variance), (pose_0, variance_0) in zip(with_sharing, without):
        assert np.array_equal(pose, pose_0) and np.array_equal(variance, variance_0)
    # the first image's forward pass is the unshared one: 6 distinct images, then none new, then one
    assert shared.evaluated == 7
    assert np.array_equal(without[0][0], model(images)[0])  # the unshared path is the plain forward pass


@pytest.fixture(scope="module")
def tiny_causal(tmp_path_factory):
    """The causal model at 16 px, an untrained tiny pose encoder and decoder, 40 steps."""
    path = tmp_path_factory.mktemp("pose") / "pose.pt"
    pe.save_encoder(path, tiny_pose_model(1), preset("tiny"), RESOLUTION)
    return configuration.load(overrides={"experiment.resolution": RESOLUTION, "experiment.steps": 40,
                                         "experiment.decoders": ["conv"], "causal.conv_pose_encoder": str(path),
                                         "causal.vae_pose_encoder": str(path)}, model_name="causal")


def participants_batch(config: dict, count: int) -> list:
    """Every cell of the protocol for ``count`` participants, each its own seed and timing noise, in one batch."""
    trials = []
    for number in range(count):
        own = (("causal.timing_noise_sd", 0.05 + 0.05 * number),)
        mine = configuration.merge(config, {"experiment": {"seed": 100 + number}})
        trials += [protocol.make_trial(mine, "conv", condition, stimulation, 0, own)
                   for condition in config["experiment"]["conditions"]
                   for stimulation in config["experiment"]["stimulations"]]
    return trials


def test_a_causal_batch_with_sharing_is_the_unshared_one_bit_for_bit(tiny_causal, monkeypatch):
    from rhi.components.vision.component import Decoder, GenerativeModel
    from rhi.components.vision.networks import build

    pe.STORE.clear()
    made = []
    plain = scene.pose_encoders

    def recording(share):
        def factory(config, kind, threads):
            make = plain(config, kind, threads)

            def build_one(name):
                component = make(name)
                component.share = share
                made.append(component)
                return component
            return build_one
        return factory

    trials = participants_batch(tiny_causal, 3)  # 3 participants x 3 conditions x 2 stimulations
    results = []
    for share in (True, False):
        monkeypatch.setattr(scene, "pose_encoders", recording(share))
        torch.manual_seed(0)
        decoder = GenerativeModel(build("conv", "tiny", RESOLUTION).decoder, kinematics.REST_POSE, HALF_RANGES,
                                  {"kind": "conv"})
        results.append(wiring.run_batch(Decoder(decoder, threads=1), trials, tiny_causal))
    shared, unshared = made
    assert shared.sharing and not unshared.sharing
    # 18 trials see 3 pictures a step (one per rubber arm; sync and async show the same ball): at most 3 of 18
    assert 0 < shared.evaluated <= 3 * 41
    assert set(results[0].values) == set(results[1].values)
    for path, values in results[0].values.items():
        assert np.array_equal(values, results[1].values[path], equal_nan=True), path
    assert np.ptp(results[0].values["brain.mu"][-1], axis=0).max() > 0  # the participants differ


def test_a_causal_batch_runs_no_decoder_unless_a_trial_reads_its_pixel_term(tiny_causal, monkeypatch):
    """``causal.pixel_weight = 0`` multiplies the decoder's terms by 0: the batch leaves the decoder out, and the
    brain's numbers are those of the batch that runs it (the same bits); a trial of its own weight > 0 needs it."""
    import dataclasses

    from rhi.components.vision.component import Decoder, GenerativeModel
    from rhi.components.vision.networks import build

    def decoder():
        torch.manual_seed(0)
        return Decoder(GenerativeModel(build("conv", "tiny", RESOLUTION).decoder, kinematics.REST_POSE, HALF_RANGES,
                                       {"kind": "conv"}), threads=1)

    trials = participants_batch(tiny_causal, 1)
    without = wiring.run_batch(decoder(), trials, tiny_causal)
    monkeypatch.setattr(scene, "reads_pixels", lambda config, trials=(): True)  # the decoder run, its terms x 0
    with_decoder = wiring.run_batch(decoder(), trials, tiny_causal)
    assert "decoder.visual_error" in with_decoder.values and "decoder.visual_error" not in without.values
    for path, values in without.values.items():
        assert np.array_equal(values, with_decoder.values[path], equal_nan=True), path
    assert np.ptp(without.values["brain.mu"][:, 0], axis=0).max() > 0  # the belief moved: not constants
    monkeypatch.undo()
    own = [dataclasses.replace(trials[0], overrides=(("causal.pixel_weight", 0.5),)), *trials[1:]]
    assert scene.reads_pixels(tiny_causal, own) and not scene.reads_pixels(tiny_causal, trials)
