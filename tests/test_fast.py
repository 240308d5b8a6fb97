"""The fast (linearised) decoder against the exact one, finite differences and an exactly linear g."""
import copy

import numpy as np
import pytest
import torch

from components.body import kinematics
from components.component import ComponentError
from components.vision.component import Decoder, GenerativeModel, resolution_weight
from components.vision import optimised as optimisation
from components.vision.fast import LinearisedDecoder
from components.vision.optimised import SubPixelTransposedConv, TangentModel, optimised
from components.vision.networks import normalise
from master import experiment
from master.bench.suite import counted_flops
from master.experiment.training_data import HALF_RANGES
from tests.test_batching import STEPS, reference_runs, three_trials, tiny_config, tiny_model

COMPARED = ("brain.mu", "brain.u_shoulder", "brain.u_elbow", "body.force_x", "decoder.visual_error")


@pytest.fixture(scope="module")
def exact():
    return reference_runs()[1]  # the exact decoder, the three trials batched


def run_fast(model, tolerance, fast_layout=True, config=None, threads=1, memory_mb=256.0):
    config = config or tiny_config()
    decoder = LinearisedDecoder(model, relinearise_tolerance=tolerance, threads=threads, fast_layout=fast_layout,
                                memory_mb=memory_mb)
    return decoder, experiment.run_batch(decoder, three_trials(config), config)


@pytest.mark.parametrize("fast_layout, threads", [(False, 1), (True, 2)])  # per-trial and whole-batch passes
def test_tolerance_zero_is_the_exact_decoder(exact, fast_layout, threads):
    decoder, fast = run_fast(tiny_model(), 0.0, fast_layout, threads=threads)
    # The initial call, then one every step but the first (the decoder steps before the brain moves mu).
    assert (decoder.relinearisations == STEPS).all()
    for path in COMPARED:  # visual_error: float32 sums of ~1e8 over the image, in another order
        rtol = 1e-5 if path == "decoder.visual_error" else 1e-6
        np.testing.assert_allclose(fast.values[path], exact.values[path], rtol=rtol, atol=1e-6, err_msg=path)


def test_small_tolerance_is_close_and_calls_the_decoder_less(exact):
    decoder, fast = run_fast(tiny_model(), 0.02)
    assert (decoder.relinearisations < STEPS).all() and decoder.decoder_calls < STEPS  # measured: 34, 9, 29; 46
    moved = np.abs(exact.values["brain.mu"][-1] - exact.values["brain.mu"][0])  # 0.1 - 1.2 deg
    error = np.abs(fast.values["brain.mu"] - exact.values["brain.mu"]).max(axis=0)  # measured: < 1e-3 deg
    assert (error <= 0.01 * moved.max()).all(), (error, moved)
    force_error = np.abs(fast.values["body.force_x"] - exact.values["body.force_x"]).max()
    assert force_error <= 0.01 * np.abs(exact.values["body.force_x"]).max()


def test_small_tolerance_holds_with_the_fewest_stored_points(exact):
    """memory_mb ~ 0 keeps 2 points per trial: old points are dropped and re-evaluated, still within the bound."""
    unlimited, _ = run_fast(tiny_model(), 0.02)
    decoder, fast = run_fast(tiny_model(), 0.02, memory_mb=1e-9)
    assert decoder._store.shape[0] == 6 and decoder.decoder_points > unlimited.decoder_points  # measured 63, 59
    moved = np.abs(exact.values["brain.mu"][-1] - exact.values["brain.mu"][0])
    assert (np.abs(fast.values["brain.mu"] - exact.values["brain.mu"]).max(axis=0) <= 0.01 * moved.max()).all()


def test_trials_within_the_tolerance_share_a_point():
    """Trial 1 starts 0.3 deg from trial 0 (tolerance 0.5) and takes its point; trial 2, 2 deg away, gets its own.
    Trial 1 then predicts g(mu0) + J(mu0) d with d = (0.3, 0), J from the model's own JVPs."""
    model = tiny_model()
    rest = np.array(kinematics.REST_POSE)
    mu = rest + np.array([[0.0, 0.0], [0.3, 0.0], [2.0, 0.0]])
    image = np.random.default_rng(1).uniform(0, 1, (3, 32, 32)).astype(np.float32)
    decoder = LinearisedDecoder(model, threads=1, fast_layout=False)
    start(decoder, 3, mu, image, relinearise_tolerance=0.5)
    assert decoder.call_sizes == [2] and decoder.relinearisations.tolist() == [1, 1, 1]
    with torch.no_grad():
        g0, jacobian = model.predict_with_jacobian(torch.tensor(rest[None], dtype=torch.float32))
    expected = (g0[0] + 0.3 * jacobian[0, 0]).numpy()
    np.testing.assert_allclose(decoder.values["prediction"][1], expected, rtol=0, atol=1e-6)
    np.testing.assert_allclose(decoder.values["prediction"][0], g0[0].numpy(), rtol=0, atol=1e-6)


class LinearImage(torch.nn.Module):
    """g(x) = A x + b, reshaped to an image: its tangent model is exact, whatever the step."""

    def __init__(self, side=32, seed=1):
        super().__init__()
        generator = torch.Generator().manual_seed(seed)
        self.side = side
        self.a = torch.nn.Parameter(0.05 * torch.randn(side * side, 2, generator=generator))
        self.b = torch.nn.Parameter(0.5 + 0.1 * torch.randn(side * side, generator=generator))

    def forward(self, x):
        return (x @ self.a.T + self.b).view(-1, self.side, self.side)


def test_an_exactly_linear_decoder_needs_one_linearisation():
    model = GenerativeModel(LinearImage(), kinematics.REST_POSE, HALF_RANGES)
    config = tiny_config()
    config["decoder"]["visual_variance"] = 0.1  # mu moves 0.1 - 0.8 deg
    exact_run = experiment.run_batch(Decoder(model, threads=1), three_trials(config), config)
    decoder, fast = run_fast(model, 1e6, config=config)
    assert (decoder.relinearisations == 1).all() and decoder.decoder_calls == 1  # identical start: one call
    assert np.abs(exact_run.values["brain.mu"][-1] - exact_run.values["brain.mu"][0]).max() > 0.1
    for path in COMPARED:
        np.testing.assert_allclose(fast.values[path], exact_run.values[path], rtol=1e-5, atol=1e-5, err_msg=path)


def start(component, batch, mu, image, **parameters):
    component.instantiate(batch)
    for name, value in parameters.items():
        component.set(name, value)
    component.setup_experiment(0.0, 1.0)
    component.enter_initialization_mode()
    component.set("mu", mu)
    component.set("image", image)
    component.exit_initialization_mode()


def test_one_step_against_finite_differences_and_numpy():
    """Linearised at mu0, the step predicts g(mu0) + J (mu - mu0) with J from central differences, and the
    drive is J^T (s_v - prediction) * 256^2/(H W) / Sigma_v in float64; a trial past its tolerance
    (and only that one) is re-linearised at its new mu and predicts g(mu) itself."""
    model = tiny_model()
    rest = np.array(kinematics.REST_POSE)
    mu0 = np.array([rest, rest + [3.0, -2.0]])
    image = np.random.default_rng(0).uniform(0, 1, (2, 32, 32)).astype(np.float32)
    decoder = LinearisedDecoder(model, threads=1, fast_layout=False)
    start(decoder, 2, mu0, image, relinearise_tolerance=[0.5, 0.05], visual_variance=2.0)
    step = np.array([[0.2, -0.3], [0.1, 0.0]])  # trial 0 within its tolerance, trial 1 beyond
    decoder.set("mu", mu0 + step)
    decoder.do_step(0.0, 0.02)
    assert decoder.relinearisations.tolist() == [1, 2]

    decoder64 = copy.deepcopy(model.decoder).double()

    def g(mu):  # in float64, so that the central differences are accurate
        with torch.no_grad():
            return decoder64(torch.from_numpy(normalise(mu, rest, np.array(HALF_RANGES)))[None])[0].numpy()

    delta = 1e-2  # deg; the decoder is piecewise linear (ReLU), central differences are exact inside a piece
    jacobian = np.stack([(g(mu0[0] + d) - g(mu0[0] - d)) / (2 * delta) for d in np.eye(2) * delta])  # (2, 32, 32)
    predicted = g(mu0[0]) + np.tensordot(step[0], jacobian, axes=1)
    np.testing.assert_allclose(decoder.values["prediction"][0], predicted, rtol=0, atol=1e-6)
    precision = resolution_weight(32, 32) / 2.0
    drive = np.tensordot(jacobian, image[0] - predicted, axes=([1, 2], [0, 1])) * precision
    np.testing.assert_allclose(decoder.values["visual_drive"][0], drive, rtol=1e-3)  # float32 sums
    error = 0.5 * ((image[0] - predicted) ** 2).sum() * precision
    np.testing.assert_allclose(decoder.values["visual_error"][0], error, rtol=1e-4)
    np.testing.assert_allclose(decoder.values["prediction"][1], g(mu0[1] + step[1]), rtol=0, atol=1e-6)


def test_bad_tolerance_is_named():
    decoder = LinearisedDecoder(tiny_model(), threads=1)
    decoder.instantiate(1)
    with pytest.raises(ComponentError, match="relinearise_tolerance"):
        decoder.set("relinearise_tolerance", -0.1)
    assert decoder.variables["relinearise_tolerance"].unit == "deg"
    assert set(Decoder(tiny_model()).variables) | {"relinearise_tolerance"} == set(decoder.variables)


def test_optimised_jacobians_equal_torch_func_jvp():
    """GenerativeModel.predict_with_jacobian's dual numbers give torch.func.jvp's columns bitwise; the written-out
    tangents in channels-last agree to float rounding, with half the FLOPs."""
    model = tiny_model()
    mu = torch.tensor(np.array(kinematics.REST_POSE) + [[0.0, 0.0], [5.0, -7.0], [-20.0, 30.0]], dtype=torch.float32)
    with torch.no_grad():
        reference = model.predict_with_jacobian(mu)
        for joint in range(2):
            prediction, column = torch.func.jvp(model, (mu,), (torch.eye(2)[joint].expand(3, 2),))
            assert torch.equal(prediction, reference[0]) and torch.equal(column, reference[1][:, joint])
        fast = optimised(model)
        assert isinstance(fast, TangentModel)
        for got, want in zip(fast.predict_with_jacobian(mu), reference):
            torch.testing.assert_close(got, want, rtol=0, atol=1e-5 * want.abs().max().item())
        flops = [counted_flops(lambda m=m: m.predict_with_jacobian(mu)) for m in (model, fast)]
    assert reference[1].abs().max() > 0  # a real Jacobian
    # Half the FLOPs, but for the last layer (ConvT 8 -> 1 on 16 x 16, 2 x 8 x 16 x 256 FLOPs) run as a sub-pixel
    # 3x3 convolution with 4 outputs (2.25x the FLOPs), for 3 beliefs x (primal + 2 tangents).
    assert flops[1] == flops[0] // 2 + 3 * 3 * (2.25 - 1) * (2 * 8 * 16 * 256)


def test_chunks_of_trials_give_the_whole_batch(monkeypatch):
    """Tiny at 32 x 32: feature maps of 16 x 4^2, 16 x 8^2 (two), 8 x 16^2 (two), the sub-pixel 4 x 16^2 and
    1 x 32^2 floats, the largest 2048; a budget of one trial's three rows makes chunks of one."""
    model = optimised(tiny_model())
    assert optimisation.largest_feature_map(model.decoder) == 8 * 16 * 16
    mu = torch.tensor(np.array(kinematics.REST_POSE) + [[0.0, 0.0], [5.0, -7.0], [-20.0, 30.0]], dtype=torch.float32)
    with torch.no_grad():
        whole = model.predict_with_jacobian(mu)
        monkeypatch.setattr(optimisation, "ACTIVATION_BUDGET", 3 * 4 * 2048)
        chunked = model.predict_with_jacobian(mu)
    for got, want in zip(chunked, whole):
        torch.testing.assert_close(got, want, rtol=0, atol=1e-6)


def test_sub_pixel_convolution_is_the_transposed_convolution():
    torch.manual_seed(0)
    layer = torch.nn.ConvTranspose2d(5, 1, 4, 2, 1)
    sub_pixel = SubPixelTransposedConv(layer)
    assert SubPixelTransposedConv.applies_to(layer) and not SubPixelTransposedConv.applies_to(
        torch.nn.ConvTranspose2d(5, 2, 4, 2, 1))
    inputs = torch.randn(3, 5, 7, 9, dtype=torch.float64)
    with torch.no_grad():
        want = layer.double()(inputs)
        got = sub_pixel.double()(inputs)
    assert got.shape == want.shape == (3, 1, 14, 18)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-12)
