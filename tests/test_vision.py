"""The visual decoder: networks, the Decoder component's drive against autograd and finite
differences, resolution scaling, and safe checkpoint loading."""
import pickle
import re

import numpy as np
import pytest
import torch

from rhi.components.component import ComponentError, Status
from rhi.components.vision import checkpoint
from rhi.components.vision.component import Decoder, GenerativeModel, jacobian_images
from rhi.components.vision.networks import PRESETS, build
from rhi.master import System, simulate
from tests.toys import Image

REST, HALF = (147.7, -91.2), (40.0, 50.0)
RES = 16


def parameter_count(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def random_model(kind="conv", seed=0, resolution=RES):
    """A tiny decoder with random weights (non-trivial Jacobians), float32, eval mode."""
    torch.manual_seed(seed)
    model = build(kind, "tiny", resolution)
    with torch.no_grad():  # a steep input layer and an output off the sigmoid's flat ends: large gradients
        model.decoder.dense[0].weight.mul_(30.0)
        model.decoder.convolutions[-2].bias.fill_(-0.5)
    return model.eval().requires_grad_(False)


def decoder_component(model, batch, variance=2.5, mu=None, image=None):
    component = Decoder(GenerativeModel(model.decoder, REST, HALF), threads=1)
    component.instantiate(batch)
    component.set("visual_variance", variance)
    rng = np.random.default_rng(1)
    component.set("mu", np.asarray(REST) + rng.uniform(-30, 30, (batch, 2)) if mu is None else mu)
    component.set("image", rng.uniform(0, 1, (batch, RES, RES)).astype(np.float32) if image is None else image)
    component.setup_experiment(0.0, 1.0)
    component.enter_initialization_mode()
    component.exit_initialization_mode()
    return component


def test_paper_preset_has_the_papers_layers_at_256():
    decoder = build("conv", "paper", 256).decoder
    assert [m.out_features for m in decoder.dense if isinstance(m, torch.nn.Linear)] == [1024, 128 * 8 * 8]
    kinds = [(type(m).__name__, m.out_channels, m.kernel_size, m.stride, m.padding)
             for m in decoder.convolutions if hasattr(m, "out_channels")]
    stages = [("ConvTranspose2d", c, (4, 4), (2, 2), (1, 1)) for c in (128, 64, 32, 16)]
    expected = [layer for c, t in zip((128, 64, 32, 16), stages) for layer in (t, ("Conv2d", c, (3, 3), (1, 1), (1, 1)))]
    assert kinds == expected + [("ConvTranspose2d", 1, (4, 4), (2, 2), (1, 1))]
    assert isinstance(decoder.convolutions[-1], torch.nn.Sigmoid)
    with torch.no_grad():
        assert decoder(torch.zeros(1, 2)).shape == (1, 256, 256)


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_preset_builds_both_decoders_sharing_one_decoder(name):
    resolution = PRESETS[name].resolution
    conv, vae = build("conv", name, resolution), build("vae", name, resolution)
    assert parameter_count(conv.decoder) == parameter_count(vae.decoder) and conv.encoder is None
    with torch.no_grad():
        mean, log_variance = vae.encoder(torch.rand(3, resolution, resolution))
    assert mean.shape == log_variance.shape == (3, 2)


def test_bad_preset_kind_and_resolution_are_named():
    with pytest.raises(ComponentError, match="preset = 'huge'"):
        build("conv", "huge")
    with pytest.raises(ComponentError, match="decoder = 'gan'"):
        build("gan", "tiny")
    with pytest.raises(ComponentError, match="resolution = 20"):
        build("conv", "tiny", 20)


def reference_jacobian(model, mu_deg):
    """J (R, R, 2) per degree by reverse-mode autograd, in float64, normalisation written out here."""
    decoder = build("conv", "tiny", RES).double().eval().requires_grad_(False)
    decoder.load_state_dict({k: v.double() for k, v in model.state_dict().items()})
    rest, half = torch.tensor(REST, dtype=torch.float64), torch.tensor(HALF, dtype=torch.float64)
    g = lambda mu: decoder.decoder(((mu - rest) / half)[None])[0]
    mu = torch.tensor(mu_deg, dtype=torch.float64)
    return g, torch.autograd.functional.jacobian(g, mu, vectorize=True)  # reverse mode, batched


def test_drive_is_j_transpose_error_over_variance_with_autograd_jacobian_and_finite_differences():
    model, batch, variance = random_model(), 3, 2.5
    component = decoder_component(model, batch, variance)
    mu, image = component.get("mu"), component.get("image")
    scale = 256 * 256 / (RES * RES)
    for trial in range(batch):
        g, jacobian = reference_jacobian(model, mu[trial])
        error = torch.from_numpy(image[trial]).double() - g(torch.tensor(mu[trial]))
        drive = torch.einsum("hwk,hw->k", jacobian, error).numpy() * scale / variance
        # float32 against float64: the drive's sum over RES^2 pixels within N u of the largest, the images (<= 1)
        # within a few roundings (16 u)
        np.testing.assert_allclose(component.get("visual_drive")[trial], drive, rtol=0,
                                   atol=RES * RES * 2.0 ** -24 * abs(drive).max() + 1e-5 * abs(drive).max())
        np.testing.assert_allclose(component.get("prediction")[trial], g(torch.tensor(mu[trial])).numpy(), atol=1e-6)
        # central finite differences of the forward pass, per degree
        step = 1e-4
        columns = [(g(torch.tensor(mu[trial] + d)) - g(torch.tensor(mu[trial] - d))) / (2 * step)
                   for d in (np.array([step, 0.0]), np.array([0.0, step]))]
        finite = np.stack([c.numpy() for c in columns])
        mine = jacobian_images(component.model, mu[trial:trial + 1])[0]
        # central differences: truncation step^2/6 g''' and float64 rounding 1e-16/step, both far below; the
        # float32 Jacobian's rounding after the decoder's layers (<= 1e-5 relative) gives the 1e-4
        np.testing.assert_allclose(mine, finite, rtol=1e-4, atol=1e-4 * abs(finite).max())
        assert abs(finite).max() > 1e-4  # the check is not vacuous
        # error and stiffness: half the sum of squares and the largest eigenvalue of J^T J, both weighted
        np.testing.assert_allclose(component.get("visual_error")[trial],  # a float32 sum of RES^2 squares: N u
                                   0.5 * float((error ** 2).sum()) * scale / variance, rtol=RES * RES * 2.0 ** -24)
        gram = np.einsum("hwk,hwl->kl", jacobian.numpy(), jacobian.numpy()) * scale / variance
        np.testing.assert_allclose(component.get("visual_stiffness")[trial], np.linalg.eigvalsh(gram)[-1], rtol=1e-5)


def test_drive_does_not_depend_on_resolution():
    """Upsampling image and prediction by pixel replication leaves drive, error and stiffness unchanged."""
    model = random_model()

    class Upsampled(torch.nn.Module):
        def forward(self, x):
            return model.decoder(x).repeat_interleave(2, 1).repeat_interleave(2, 2)

    rng = np.random.default_rng(3)
    mu = np.asarray(REST) + rng.uniform(-20, 20, (2, 2))
    image = rng.uniform(0, 1, (2, RES, RES)).astype(np.float32)
    small = decoder_component(model, 2, mu=mu, image=image)
    large = Decoder(GenerativeModel(Upsampled(), REST, HALF), threads=1)
    large.instantiate(2)
    large.set("visual_variance", 2.5)
    large.set("mu", mu)
    large.set("image", image.repeat(2, 1).repeat(2, 2))
    large.enter_initialization_mode()
    large.exit_initialization_mode()
    for name in ("visual_drive", "visual_error", "visual_stiffness"):
        expected = small.get(name)
        np.testing.assert_allclose(large.get(name), expected, rtol=1e-5, atol=1e-5 * abs(expected).max())


def test_outputs_are_new_arrays_each_step_and_bad_belief_fails_the_step():
    component = decoder_component(random_model(), 2)
    before = {name: component.get(name) for name in ("visual_drive", "prediction")}
    snapshot = {name: value.copy() for name, value in before.items()}
    component.set("mu", np.asarray(REST) + np.array([[5.0, 5.0], [-5.0, 3.0]]))
    assert component.do_step(0.0, 0.02) == Status.OK
    for name, value in before.items():
        assert component.get(name) is not value and np.array_equal(value, snapshot[name])
    assert component.get("prediction").dtype == np.float32
    component.set("mu", np.array([[np.nan, 0.0], [147.0, -90.0]]))
    assert component.do_step(0.02, 0.02) == Status.ERROR and "trial 0" in component.last_reason


def test_decoder_runs_in_a_system_and_declares_a_valid_model_description():
    model = random_model()
    decoder = Decoder(GenerativeModel(model.decoder, REST, HALF), threads=1)
    system = System([Image("camera", RES), decoder], [("camera.image", "decoder.image")])
    result = simulate(system, stop_time=0.06, step_size=0.02, batch_size=2, record=["decoder.visual_drive"],
                      parameters={"decoder.visual_variance": 10.0})
    mu = torch.tensor([REST, REST], dtype=torch.float32)
    with torch.no_grad():
        prediction, jacobian = decoder.model.predict_with_jacobian(mu)
    image = torch.full((2, RES, RES), float(np.float32(np.sin(0.04))))  # the toy camera's last image
    expected = torch.einsum("bkhw,bhw->bk", jacobian, image - prediction) * 256 / 10.0
    np.testing.assert_allclose(result.values["decoder.visual_drive"][-1], expected.numpy(), rtol=1e-5)
    assert "visual_drive" in decoder.model_description()


# -- checkpoints -------------------------------------------------------------------------------

METADATA = {"kind": "conv", "preset": "tiny", "sizes": {"hidden": 64, "channels": [16, 8], "resolution": 16},
            "resolution": RES, "rest_pose": list(REST), "half_ranges": list(HALF), "data_hash": "abc",
            "validation_mse": 0.01, "seconds": 1.5}


def test_checkpoint_round_trip_gives_the_same_predictions(tmp_path):
    model = random_model("vae")
    path = tmp_path / "vae.pt"
    save(path, model, {**METADATA, "kind": "vae"})
    raw = torch.load(path, weights_only=True)  # loadable without unpickling any object
    assert set(raw) == {"format", "metadata", "weights"}
    loaded = GenerativeModel.from_checkpoint(path, resolution=RES, rest_pose=REST, half_ranges=HALF)
    mu = torch.tensor([[150.0, -80.0], [120.0, -100.0]])
    with torch.no_grad():
        np.testing.assert_array_equal(loaded(mu).numpy(), GenerativeModel(model.decoder, REST, HALF)(mu).numpy())
    assert loaded.metadata["data_hash"] == "abc" and checkpoint.load(path)[1]["kind"] == "vae"


class Payload:
    ran = False

    def __reduce__(self):
        return (setattr, (Payload, "ran", True))


@pytest.mark.parametrize("case, message", [
    ("missing", "no such checkpoint"),
    ("truncated", "truncated or damaged checkpoint"),
    ("text", "not a zip archive as torch.save writes"),
    ("pickle", "not a zip archive as torch.save writes"),
    ("pickle_in_zip", "holds objects other than tensors"),
    ("no_tag", "no 'rhi-visual-decoder/1' format tag"),
    ("bad_json", "metadata is missing or is not JSON"),
    ("no_hash", "metadata 'data_hash' is missing"),
    ("wrong_shapes", "weights do not fit a conv decoder"),
    ("nan", "NaN or infinity"),
    ("resolution", "trained at resolution 16 px but the camera renders 32 px"),
    ("rest_pose", "trained with rest_pose = (147.7, -91.2) deg but the body uses (147.8, -91.2)"),
    ("half_ranges", "half_ranges"),
])
def test_bad_checkpoints_give_one_clear_error_naming_the_file(tmp_path, case, message):
    path = tmp_path / "decoder.pt"
    model = random_model()
    save(path, model, METADATA)
    good = path.read_bytes()
    payload = torch.load(path, weights_only=True)
    expect = {"resolution": RES, "rest_pose": REST, "half_ranges": HALF}
    if case == "missing":
        path.unlink()
    elif case == "truncated":
        path.write_bytes(good[: len(good) // 2])
    elif case == "text":
        path.write_text("shoulder,elbow\n1,2\n")
    elif case == "pickle":
        path.write_bytes(pickle.dumps(Payload()))
    elif case == "pickle_in_zip":
        torch.save({**payload, "extra": Payload()}, path)
    elif case == "no_tag":
        torch.save({"weights": payload["weights"]}, path)
    elif case == "bad_json":
        torch.save({**payload, "metadata": "{not json"}, path)
    elif case == "no_hash":
        torch.save({**payload, "metadata": payload["metadata"].replace('"data_hash"', '"data_hash_"')}, path)
    elif case == "wrong_shapes":
        save(path, random_model(resolution=32), METADATA)
    elif case == "nan":
        payload["weights"]["decoder.dense.0.bias"][0] = float("nan")
        torch.save(payload, path)
    elif case == "resolution":
        expect["resolution"] = 32
    elif case == "rest_pose":
        expect["rest_pose"] = (147.8, -91.2)
    elif case == "half_ranges":
        expect["half_ranges"] = (30.0, 50.0)
    with pytest.raises(checkpoint.CheckpointError, match=re.escape(message)) as info:
        Decoder(path, **expect)
    assert str(path) in str(info.value) and isinstance(info.value, ValueError)
    assert not Payload.ran


def test_experiment_config_chooses_the_exact_or_the_fast_decoder(tmp_path):
    from rhi.components.vision.fast import LinearisedDecoder
    from rhi.master import config as configuration
    from rhi.master.decoders.cache import decoder_component
    from rhi.master.cosim import ConfigError
    from rhi.components.body.kinematics import REST_POSE
    from rhi.master.decoders.training_data import HALF_RANGES
    path = tmp_path / "conv.pt"
    save(path, random_model(), {**METADATA, "rest_pose": list(REST_POSE), "half_ranges": list(HALF_RANGES)})
    exact = decoder_component("conv", str(path), configuration.load(overrides={"experiment.resolution": RES,
                                                                                "decoder.fast": False}))
    assert type(exact) is Decoder
    config = configuration.load(overrides={"experiment.resolution": RES, "decoder.fast": True,
                                           "decoder.relinearise_tolerance": 0.05})
    fast = decoder_component("conv", str(path), config)
    fast.instantiate(2)
    assert isinstance(fast, LinearisedDecoder) and fast.get("relinearise_tolerance").tolist() == [0.05, 0.05]
    with pytest.raises(ConfigError, match="decoder.relinearise_tolerance must be >= 0"):
        configuration.load(overrides={"decoder.relinearise_tolerance": -0.1})


def save(path, model, metadata):
    with open(path, "wb") as file:
        checkpoint.write(file, model, metadata)
