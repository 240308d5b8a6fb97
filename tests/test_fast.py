"""The fast (linearised) decoder against the exact one, finite differences and an exactly linear g."""
import copy

import numpy as np
import pytest
import torch

from rhi.components.body import kinematics
from rhi.components.component import ComponentError
from rhi.components.vision.component import Decoder, GenerativeModel, resolution_weight, visual_drive
from rhi.components.vision import optimised as optimisation
from rhi.components.vision.fast import DEFAULT_TOLERANCE, LinearisedDecoder
from rhi.master.tasks.illusion.fast_check import DRIFT_BOUND
from rhi.components.vision.optimised import SubPixelTransposedConv, TangentModel, optimised
from rhi.components.vision.networks import normalise
from rhi.master.tasks import illusion as experiment
from rhi.master import config as configuration
from rhi.master.bench.suite import counted_flops
from rhi.master.decoders.training_data import HALF_RANGES
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
    for path in COMPARED:  # the same sums in another order: the visual error within N u = 32^2 u of itself,
        # the rest as the batching test derives (tests/test_batching.py)
        rtol = 32 * 32 * 2.0 ** -24 if path == "decoder.visual_error" else 1e-6
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
    expected = (g0[0] + 0.3 * jacobian[0, 0]).numpy()  # pixels <= 1, so a few float32 roundings: atol 16 u
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
    for path in COMPARED:  # an exact tangent model: only float32 rounding differs, the drive's sum over 32^2
        # pixels within N u = 6e-5 of itself; rtol 1e-5 of mu (~150 deg) is 1.5e-3 deg, 20x the 0.8 deg it moves
        # times N u; the visual error as a float32 sum (N u)
        rtol = 32 * 32 * 2.0 ** -24 if path == "decoder.visual_error" else 1e-5
        np.testing.assert_allclose(fast.values[path], exact_run.values[path], rtol=rtol, atol=1e-5, err_msg=path)


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
    # float32 sums of 32^2 terms J e (N u = 6e-5 of the sum of |J e|), against a drive with cancellation
    # between pixels of either sign, |sum J e| about a tenth of sum |J e| here: rtol 1e-3
    np.testing.assert_allclose(decoder.values["visual_drive"][0], drive, rtol=1e-3)
    error = 0.5 * ((image[0] - predicted) ** 2).sum() * precision
    np.testing.assert_allclose(decoder.values["visual_error"][0], error, rtol=1e-4)  # positive terms: N u = 6e-5
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
        for got, want in zip(fast.predict_with_jacobian(mu), reference):  # other float32 sums: the sub-pixel
            # layer's 8 x 3 x 3 = 72 terms and its reordering of the layers before, within 1e-5 of the largest
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
    for got, want in zip(chunked, whole):  # the same per-trial arithmetic, chunked: images <= 1, atol 16 u
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


# -- the tolerance invariant, the squared error's d^T G d term, and the drift against the exact integrator -------
class Watched(LinearisedDecoder):
    """The fast decoder, recording at each of its steps |mu - mu0| per joint (mu0: the trial's linearisation point),
    its visual stiffness, and its drive's defect: minus the exact drive at the same mu and image (``reference``'s
    own JVPs, the exact Decoder's arithmetic)."""

    def __init__(self, model, reference, **settings):
        super().__init__(model, threads=1, **settings)
        self.reference = reference

    def initialize(self):
        self.gaps, self.defects, self.stiffness = [], [], []
        super().initialize()

    def _update(self):
        super()._update()
        mu, image, precision = self._checked_inputs()
        self.gaps.append(np.abs(mu - self._points[self._slots]))
        with torch.no_grad():
            prediction, jacobian = self.reference.predict_with_jacobian(torch.from_numpy(mu.astype(np.float32)))
            exact = visual_drive(jacobian, torch.from_numpy(image) - prediction, precision).double().numpy()
        self.defects.append(self.values["visual_drive"] - exact)
        self.stiffness.append(self.values["visual_stiffness"].copy())


@pytest.mark.parametrize("memory_mb", [256.0, 1e-9])  # 1e-9: two points per trial, old ones evicted
def test_every_step_both_joints_stay_within_the_tolerance_of_the_linearisation_point(memory_mb):
    tolerance = 0.02
    decoder = Watched(tiny_model(), tiny_model(), relinearise_tolerance=tolerance, memory_mb=memory_mb)
    config = tiny_config()
    experiment.run_batch(decoder, three_trials(config), config)
    gaps = np.array(decoder.gaps)  # (steps + 1, trials, joints)
    assert gaps.shape == (STEPS + 1, 3, 2)
    for joint in range(2):
        assert (gaps[:, :, joint] <= tolerance).all(), (joint, gaps[:, :, joint].max())
        assert gaps[:, :, joint].max() > 0.5 * tolerance  # not vacuous: each joint comes near it
    assert (decoder.relinearisations > 1).all()


def test_a_belief_moving_along_one_joint_is_relinearised_on_that_joint():
    """Trial 0 moves its elbow only, trial 1 its shoulder only, trial 2 both, 0.4 tolerance a step: each takes a new
    point every third step (at 1.2 tolerances), so |mu - mu0| <= tolerance on both joints after every step."""
    tolerance, steps = 0.05, 10
    rest = np.array(kinematics.REST_POSE)
    direction = np.array([[0.0, 1.0], [-1.0, 0.0], [1.0, -1.0]])
    image = np.random.default_rng(2).uniform(0, 1, (3, 32, 32)).astype(np.float32)
    decoder = LinearisedDecoder(tiny_model(), threads=1, fast_layout=False)
    start(decoder, 3, np.broadcast_to(rest, (3, 2)), image, relinearise_tolerance=tolerance)
    for step in range(1, steps + 1):
        mu = rest + 0.4 * tolerance * step * direction
        decoder.set("mu", mu)
        decoder.do_step(0.02 * step, 0.02)
        gap = np.abs(mu - decoder._points[decoder._slots])
        assert (gap <= tolerance + 1e-12).all(), (step, gap)
    assert decoder.relinearisations.tolist() == [4, 4, 4]  # the first, then at steps 3, 6 and 9


def test_the_squared_error_has_its_d_G_d_term():
    """With s_v = g(mu0), the linearised error at mu0 + d is J0 d alone: visual_error = 1/2 d^T J0^T J0 d * precision,
    drive = -J0^T J0 d * precision. g is exactly linear, so the exact Decoder must give the same."""
    module = LinearImage()
    model = GenerativeModel(module, kinematics.REST_POSE, HALF_RANGES)
    rest = np.array(kinematics.REST_POSE)
    steps = np.array([[0.3, -0.2], [-0.5, 0.0], [0.0, 0.4]])
    with torch.no_grad():
        seen = model(torch.tensor(np.broadcast_to(rest, (3, 2)), dtype=torch.float32)).numpy()
    fast = LinearisedDecoder(model, threads=1, fast_layout=False)
    start(fast, 3, np.broadcast_to(rest, (3, 2)), seen, relinearise_tolerance=1.0, visual_variance=0.01)
    fast.set("mu", rest + steps)
    fast.do_step(0.0, 0.02)
    assert fast.relinearisations.tolist() == [1, 1, 1]  # still at mu0: d = steps
    exact = Decoder(model, threads=1)
    start(exact, 3, rest + steps, seen, visual_variance=0.01)

    jacobian = module.a.detach().double().numpy() / np.array(HALF_RANGES)  # (pixels, 2), per degree
    gram = jacobian.T @ jacobian
    precision = resolution_weight(32, 32) / 0.01
    error = 0.5 * np.einsum("bi,ij,bj->b", steps, gram, steps) * precision
    assert error.min() > 0.1  # the whole error is the d^T G d term here (0 without it)
    for component in (fast, exact):  # a float32 sum of 32^2 positive terms: N u = 6e-5
        np.testing.assert_allclose(component.values["visual_error"], error, rtol=1e-4)
        drive = -steps @ gram * precision  # float32 images: a pixel's rounding is 1e-7 of the largest term
        np.testing.assert_allclose(component.values["visual_drive"], drive, rtol=0, atol=1e-4 * np.abs(drive).max())


@pytest.fixture(scope="module")
def quick_conv(quick_cache):
    """The --quick conv decoder the session trained (tests/conftest.py)."""
    from rhi.master.decoders.training import load_decoder
    return load_decoder(next(quick_cache.glob("conv-*.pt")), 32)


def test_fast_drift_is_the_exact_drift_to_the_first_order_error_of_its_drive(quick_conv):
    """The trained --quick conv decoder, the quick protocol's six trials (300 steps), the default tolerance.

    The bound. The fast belief obeys the exact belief's equation but for its drive, which differs from the exact
    drive at the same mu and image by the defect delta_n (recorded each step). To first order the belief error
    e = mu_fast - mu_exact then follows e_{n+1} = (1 - h/Sigma_p) e_n + h gamma_n delta_n: so |e_N| <= E =
    sum_n h gamma_n |delta_n| (1 - h/Sigma_p)^(N-1-n). Neglected: the visual term's own response to e, at a rate
    gamma * visual_stiffness, checked here to stay below 20 % of the proprioceptive rate 1/Sigma_p; hence the
    factor 1.25. Measured: |e_N| / E from 0.93 to 3.6 over tolerances 0.0025-0.08 deg and both quick decoders
    (0.97-3.0 here). The final drift error is then within the hand's Jacobian times 1.25 E, and within the fast
    check's bound (rhi.master.tasks.illusion.fast_check.DRIFT_BOUND) of the largest drift; the final error does not fall
    monotonically with the tolerance (docs/decoders.md, "Fast mode")."""
    config = configuration.load(quick=True)
    trials = [t for t in experiment.plan(config) if t.decoder == "conv"]
    exact = experiment.run_batch(Decoder(quick_conv, threads=1), trials, config)
    decoder = Watched(quick_conv, quick_conv, relinearise_tolerance=DEFAULT_TOLERANCE)
    fast = experiment.run_batch(decoder, trials, config)
    h, sigma_p = config["experiment"]["step_size"], config["brain"]["proprioceptive_variance"]
    gamma = fast.values["brain.gamma"]  # row n + 1: the gamma of step n

    gaps = np.array(decoder.gaps)
    assert (gaps <= DEFAULT_TOLERANCE).all() and (gaps.max(axis=(0, 1)) > 0.5 * DEFAULT_TOLERANCE).all()
    # Decoder call n + 1 serves step n (call 0 is the initialization's, at the same mu as step 0's).
    defects = np.linalg.norm(np.array(decoder.defects), axis=2)
    assert (gamma[1:] * np.array(decoder.stiffness)[1:] * sigma_p).max() < 0.2
    bound = np.zeros(len(trials))
    for n in range(config["experiment"]["steps"]):
        bound = (1 - h / sigma_p) * bound + h * gamma[n + 1] * defects[n + 1]
    error = np.linalg.norm(fast.values["brain.mu"][-1] - exact.values["brain.mu"][-1], axis=1)
    assert (error <= 1.25 * bound).all(), (error, bound)
    assert error.max() > 1e-5  # the fast mode is not exact here: the bound has something to bound

    drift_exact, drift_fast = (experiment.measures(run)["drift_cm"][-1] for run in (exact, fast))
    hand = np.linalg.norm(kinematics.jacobian(*fast.values["brain.mu"][-1].T)[:, 0, :], axis=1)  # m/deg, |dx/dq|
    assert (np.abs(drift_fast - drift_exact) <= 100 * hand * 1.25 * bound + 1e-9).all()
    assert np.abs(drift_fast - drift_exact).max() <= DRIFT_BOUND * np.abs(drift_exact).max()
