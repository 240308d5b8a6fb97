"""Contracts between the real decoder and the brain: the free energy F the brain reports is the one its
belief descends (-dF/dmu = mu_dot, by finite differences and by autograd); and every test double against the
real component it stands for, on a case both run: the linear double of tests/linear_decoder.py means what the
real Decoder means, the sweep's fake outcome (tests/sweep_tasks.py) what trial_outcome means, and the toys of
tests/toys.py have the ports of the components they replace."""
import copy
import inspect

import numpy as np
import pytest
import torch

from rhi.components.body import kinematics
from rhi.components.component import ComponentError
from rhi.components.brain import Brain
from rhi.components.vision.component import Decoder, GenerativeModel, jacobian_images, resolution_weight
from rhi.components.vision.networks import build, normalise
from tests.linear_decoder import LinearDecoder
from tests.sweep_tasks import fake_outcome

REST, HALF = np.array(kinematics.REST_POSE), np.array([40.0, 50.0])
RES, H = 16, 0.02
SIGMA_P, GAMMA0, VISUAL_VARIANCE = 2.0, 0.5, 0.005
EPS = 2.0 ** -4  # deg; mu and mu +- EPS are exact float32 numbers (mu is on a 2^-6 grid), so the step is exact


def tiny_model():
    """An untrained tiny ConvDecoder, its last layer steepened.

    Untrained, its pre-sigmoid output varies about 100 times less with mu than across pixels, so g is
    nearly flat in mu. The last transposed convolution's weight times 100, its bias centring the sigmoid,
    gives Jacobians of a trained decoder's order without adding ReLU kinks (they all sit before that layer).
    """
    torch.manual_seed(0)
    decoder = build("conv", "tiny", RES).decoder
    with torch.no_grad():
        last = decoder.convolutions[-2]
        last.weight.mul_(100.0)
        last.bias.zero_()
        features = decoder.dense(torch.zeros(1, 2)).view(1, decoder.start_channels, decoder.start, decoder.start)
        last.bias.fill_(-float(decoder.convolutions[:-1](features).mean()))
    return GenerativeModel(decoder, REST, HALF)


def decoded(model, mu, image, variance=VISUAL_VARIANCE):
    """The Decoder component's outputs for beliefs mu (B, 2) and images (B, R, R), past initialization."""
    decoder = Decoder(model, threads=1)
    decoder.instantiate(len(mu))
    decoder.set("visual_variance", variance)
    decoder.setup_experiment(0.0, 1.0)
    decoder.enter_initialization_mode()
    decoder.set("mu", mu)
    decoder.set("image", image)
    decoder.exit_initialization_mode()
    assert decoder.last_reason == ""
    return {name: decoder.get(name) for name in ("visual_drive", "visual_error", "visual_stiffness", "prediction")}


def brain_step(mu, s_p, visual):
    """One Brain step from belief mu with the inputs set by hand; returns mu_dot = (mu_new - mu)/h and F."""
    brain = Brain()
    brain.instantiate(len(mu))
    for name, value in {"mu0": mu, "proprioceptive_variance": SIGMA_P, "gamma0": GAMMA0}.items():
        brain.set(name, value)
    brain.setup_experiment(0.0, 1.0)
    brain.enter_initialization_mode()
    inputs = {"q_shoulder": s_p[:, 0], "q_elbow": s_p[:, 1], "visual_time": -np.inf, "tactile_time": -np.inf,
              **{name: visual[name] for name in ("visual_drive", "visual_error", "visual_stiffness")}}
    for name, value in inputs.items():
        brain.set(name, value)
    brain.exit_initialization_mode()
    assert brain.do_step(0.0, H) == 0, brain.last_reason
    assert np.all(brain.get("gamma") == GAMMA0)  # no events: gamma holds at its floor
    return (brain.get("mu") - mu) / H, brain.get("free_energy")


def problem(model):
    """Beliefs on the 2^-6 grid, the sensed angles, and as seen images the decoder's own of other poses
    (an untrained decoder is far from any camera image, whose residual would dwarf its gradient).
    The beliefs are ones with no ReLU kink of this decoder within +-EPS (checked in the test)."""
    mu = np.round((REST + np.array([[8.0, -14.0], [2.5, 26.0], [21.5, -28.0]])) * 64) / 64
    s_p = mu + np.array([[0.5, -0.3], [-1.0, 2.0], [0.2, 0.1]])
    with torch.no_grad():
        image = model(torch.tensor(mu + [[3.0, -4.0], [-2.0, 5.0], [4.0, 2.0]], dtype=torch.float32)).numpy()
    return mu, s_p, image


def proprioceptive_term(mu, s_p):
    return ((s_p - mu) ** 2).sum(axis=1) / (2 * SIGMA_P)


def float64_terms(model, mu, image):
    """g(mu) by a float64 copy of the decoder, F's visual term 1/2 |s_v - g|^2 * precision, and its gradient."""
    decoder64 = copy.deepcopy(model.decoder).double()
    belief = torch.tensor(mu, dtype=torch.float64, requires_grad=True)
    prediction = decoder64(normalise(belief, torch.from_numpy(REST), torch.from_numpy(HALF)))
    precision = resolution_weight(RES, RES) / VISUAL_VARIANCE
    visual_error = 0.5 * ((torch.from_numpy(image).double() - prediction) ** 2).sum(dim=(1, 2)) * precision
    (gradient,) = torch.autograd.grad(visual_error.sum(), belief)
    return prediction.detach().numpy(), visual_error.detach().numpy(), gradient.numpy()


def test_belief_descends_the_reported_free_energy_by_finite_differences():
    """-dF/dmu by central differences of F(mu) = sum (s_p - mu)^2/(2 Sigma_p) + gamma * visual_error(mu), the real
    decoder re-evaluated at mu +- EPS, equals the brain's mu_dot = (mu_new - mu)/h.

    Tolerance, from float32: the decoder computes g in float32, off the float64 g by delta per pixel at
    most (measured here); in the difference quotient that moves F by at most
    gamma * precision * |e|_1 * delta / EPS, with e = s_v - g. The float32 sum of the R^2 squares adds
    gamma * R^2 2^-24 visual_error / EPS. A ReLU kink within +-EPS would bias the quotient itself: the
    same quotient in float64 matches autograd to 1e-6 of the gradient, so there is none, and the
    sigmoid's truncation error EPS^2/6 F''' is as small. The brain's Euler step and the (exactly
    quadratic) proprioceptive term add about 1e-12. The visual rate of every trial is checked to be
    ten times the tolerance or more.
    """
    model = tiny_model()
    mu, s_p, image = problem(model)
    visual = decoded(model, mu, image)
    mu_dot, _ = brain_step(mu, s_p, visual)

    def energy(belief):
        return proprioceptive_term(belief, s_p) + GAMMA0 * decoded(model, belief, image)["visual_error"]

    steps = [EPS * e for e in np.eye(2)]
    gradient = np.stack([(energy(mu + d) - energy(mu - d)) / (2 * EPS) for d in steps], axis=1)

    # The tolerance's ingredients, and the float64 difference quotient exact (no kink within +-EPS).
    precision = resolution_weight(RES, RES) / VISUAL_VARIANCE
    delta = max(np.abs(decoded(model, mu + d, image)["prediction"] - float64_terms(model, mu + d, image)[0]).max()
                for d in steps + [-d for d in steps])
    quotient = np.stack([(float64_terms(model, mu + d, image)[1] - float64_terms(model, mu - d, image)[1]) / (2 * EPS)
                         for d in steps], axis=1)
    exact = float64_terms(model, mu, image)[2]
    np.testing.assert_allclose(quotient, exact, rtol=0, atol=1e-6 * np.abs(exact).max())
    residual = np.abs(image - visual["prediction"]).sum(axis=(1, 2))
    tolerance = GAMMA0 * (precision * residual * delta + RES * RES * 2.0 ** -24 * visual["visual_error"]) / EPS

    visual_rate = GAMMA0 * np.linalg.norm(visual["visual_drive"], axis=1)  # deg/s
    assert (visual_rate > 10 * tolerance).all() and visual_rate.max() > 0.1, (visual_rate, tolerance)
    np.testing.assert_array_less(np.abs(mu_dot + gradient), np.broadcast_to(tolerance[:, None], mu.shape))


def float64_jacobian(model, mu):
    """dg/dmu (B, 2, R, R) of a float64 copy of the decoder, by autograd (torch.func.jacrev)."""
    decoder64 = copy.deepcopy(model.decoder).double()
    rest, half = torch.from_numpy(REST), torch.from_numpy(HALF)

    def image(belief):
        return decoder64(normalise(belief[None], rest, half))[0]

    belief = torch.tensor(mu, dtype=torch.float64)
    return torch.stack([torch.func.jacrev(image)(one) for one in belief]).permute(0, 3, 1, 2).numpy()


def test_belief_descends_the_reported_free_energy_by_autograd_in_float64():
    """The same gradient by torch autograd through a float64 copy of the decoder, and the brain's reported
    F against F computed here independently.

    Tolerances, each the worst case of the float32 arithmetic between the two sides (u = 2^-24, N = R^2
    pixels, e = s_v - g32, delta = |g32 - g64| per pixel, J32 the component's Jacobian, J64 autograd's):
    - F from the decoder's own float32 prediction, summed here in float64: only the float32 squares and
      their N-term sum separate them, at most N u of the visual term;
    - F's visual term of the float64 decoder: g32 moves each squared residual by 2|e|delta, so
      precision * sum |e| delta more;
    - the belief's rate against -dF/dmu in float64: the drive precision * J^T e moves by
      precision * (sum |J32 - J64| |e| + sum |J64| delta + N u sum |J32 e|).
    The brain's own float64 arithmetic adds about 1e-15 relative to each."""
    model = tiny_model()
    mu, s_p, image = problem(model)
    visual = decoded(model, mu, image)
    mu_dot, free_energy = brain_step(mu, s_p, visual)

    g64, visual_error64, visual_gradient = float64_terms(model, mu, image)
    g32 = visual["prediction"].astype(np.float64)
    precision = resolution_weight(RES, RES) / VISUAL_VARIANCE
    pixels, u = RES * RES, 2.0 ** -24
    error = image.astype(np.float64) - g32
    delta = np.abs(g32 - g64)

    visual_error32 = 0.5 * precision * (error ** 2).sum(axis=(1, 2))
    summation = pixels * u * visual_error32
    np.testing.assert_array_less(np.abs(visual["visual_error"] - visual_error32), summation)
    np.testing.assert_array_less(np.abs(free_energy - proprioceptive_term(mu, s_p) - GAMMA0 * visual_error32),
                                 GAMMA0 * summation + 1e-12)
    float64_bound = summation + precision * (np.abs(error) * delta).sum(axis=(1, 2))
    np.testing.assert_array_less(np.abs(visual["visual_error"] - visual_error64), float64_bound)

    j32, j64 = jacobian_images(model, mu).astype(np.float64), float64_jacobian(model, mu)
    drive_bound = precision * ((np.abs(j32 - j64) * np.abs(error)[:, None]).sum(axis=(2, 3))
                               + (np.abs(j64) * delta[:, None]).sum(axis=(2, 3))
                               + pixels * u * np.abs(j32 * error[:, None]).sum(axis=(2, 3)))
    gradient = -(s_p - mu) / SIGMA_P + GAMMA0 * visual_gradient
    np.testing.assert_array_less(np.abs(mu_dot + gradient), GAMMA0 * drive_bound + 1e-12)
    assert (GAMMA0 * drive_bound < 0.1 * np.abs(GAMMA0 * visual["visual_drive"])).all()  # not vacuous


class LinearImage(torch.nn.Module):
    """g(x) = A' x + b' reshaped to (B, R, R), x the normalised angles: GenerativeModel's decoder interface."""

    def __init__(self, weight, offset, side):
        super().__init__()
        self.weight, self.offset, self.side = weight, offset, side

    def forward(self, x):
        return (x @ self.weight.T + self.offset).view(-1, self.side, self.side)


def test_the_linear_double_means_what_the_real_decoder_means():
    """LinearDecoder(A, b, s_v) and the real Decoder around g(mu) = A mu + b (in degrees) agree on every output.

    The real decoder sees the normalised x = (mu - rest)/half, so its module holds A' = A diag(half) and
    b' = b + A rest; its visual_variance is the double's times the resolution weight 256^2/R^2, so that both
    weigh a pixel by the same precision. Float32 (the real decoder) against float64 (the double)."""
    side, batch = 6, 3
    rng = np.random.default_rng(4)
    A = rng.normal(0.0, 0.01, (side * side, 2))  # per degree
    b = rng.uniform(0.2, 0.8, side * side) - A @ REST  # g(rest) in [0.2, 0.8]
    seen = rng.uniform(0.0, 1.0, side * side)
    mu = REST + rng.uniform(-20.0, 20.0, (batch, 2))
    variance = 0.7

    double = LinearDecoder(A, b, seen)
    double.instantiate(batch)
    double.set("visual_variance", variance)
    double.setup_experiment(0.0, 1.0)
    double.enter_initialization_mode()
    double.set("mu", mu)
    double.exit_initialization_mode()

    module = LinearImage(torch.tensor(A * HALF, dtype=torch.float32), torch.tensor(b + A @ REST, dtype=torch.float32),
                         side)
    real = decoded(GenerativeModel(module, REST, HALF), mu, np.broadcast_to(seen.reshape(side, side), (batch, side, side)),
                   variance=variance * resolution_weight(side, side))

    np.testing.assert_allclose(real["prediction"].reshape(batch, -1), double.get("prediction"), rtol=0, atol=1e-6)
    for name in ("visual_drive", "visual_error", "visual_stiffness"):
        expected = double.get(name)
        assert np.abs(expected).max() > 1e-4, name  # not vacuous
        np.testing.assert_allclose(real[name], expected, rtol=1e-5, atol=1e-6 * np.abs(expected).max(), err_msg=name)


# -- the sweep's stand-in trial against the real one ----------------------------------------------------------
@pytest.fixture(scope="module")
def real_outcomes(quick_cache):
    """rhi.master.tasks.illusion.trial_outcome on the --quick protocol with the session's conv decoder, three cells."""
    from rhi.master import config as configuration
    from rhi.master.tasks.illusion import trial_outcome

    config = configuration.load(quick=True)
    checkpoint = str(next(quick_cache.glob("conv-*.pt")))
    cells = [("left", "sync"), ("right", "sync"), ("left", "async")]
    return config, checkpoint, {cell: trial_outcome(config, "conv", *cell, 0, checkpoint=checkpoint) for cell in cells}


def test_the_fake_sweep_outcome_means_what_the_real_trial_outcome_means(real_outcomes):
    """tests/sweep_tasks.py's fake_outcome stands in for trial_outcome in the sweep tests: the same arguments, the
    same keys (a subset), plain floats, and the same meaning on a case both run: drift and force toward the
    rubber hand (negative Left, positive Right) under synchronous touch, gamma in [gamma0, 1] and higher for
    synchronous than asynchronous touch."""
    from rhi.master.tasks.illusion import trial_outcome

    config, _, real = real_outcomes
    parameters = list(inspect.signature(fake_outcome).parameters)
    assert parameters == list(inspect.signature(trial_outcome).parameters)[:len(parameters)]
    fake = {cell: fake_outcome(config, "conv", *cell, 0) for cell in real}
    gamma0 = config["brain"]["gamma0"]
    for outcomes in (real, fake):
        for outcome in outcomes.values():
            assert {"drift_cm", "force_n", "gamma_final"} <= set(outcome)
            assert all(isinstance(outcome[key], float) for key in ("drift_cm", "force_n", "gamma_final"))
            assert gamma0 <= outcome["gamma_final"] <= 1
        assert outcomes[("left", "sync")]["drift_cm"] < 0 < outcomes[("right", "sync")]["drift_cm"]
        assert outcomes[("left", "sync")]["force_n"] < 0 < outcomes[("right", "sync")]["force_n"]
        assert outcomes[("left", "async")]["gamma_final"] < outcomes[("left", "sync")]["gamma_final"]
    assert set(fake[("left", "sync")]) <= set(real[("left", "sync")])


def test_the_fake_and_the_real_trial_fail_alike_out_of_reach(real_outcomes):
    """A rubber hand out of the arm's reach fails the trial with a ComponentError saying so, in both."""
    from rhi.master import config as configuration
    from rhi.master.tasks.illusion import trial_outcome

    _, checkpoint, _ = real_outcomes
    # merged past the configuration's checks, which refuse it before any trial runs (tests/test_hostile_inputs.py)
    config = configuration.merge(configuration.load(quick=True), {"conditions": {"left": 1.0}})
    with pytest.raises(ComponentError, match="out of reach"):
        fake_outcome(config, "conv", "left", "sync", 0)
    # The real trial is a batch of one whose failure is a record (rhi.master.tasks.illusion.runner.batch_outcomes), raised
    # as a RuntimeError carrying the record's "Type: message".
    with pytest.raises(RuntimeError, match="^ComponentError: .*out of reach"):
        trial_outcome(config, "conv", "left", "sync", 0, checkpoint=checkpoint)


# -- the toys and doubles stand where real components stand: same ports, and both run there ---------------------
def port(variable):
    return (variable.causality, variable.type, variable.shape, variable.element, variable.unit, variable.start,
            variable.depends_on)


def test_the_image_toys_have_the_camera_and_decoder_image_ports_and_run_with_them():
    """tests/toys.py's Image stands for the camera (an image output) and ImageSink for the decoder (an image input)
    in the master's tests: each declares the real port, and each runs under the master with the real other side."""
    from rhi.master import System, simulate
    from rhi.components.body.camera import Camera
    from tests.toys import Image, ImageSink

    model = tiny_model()
    camera, decoder = Camera(resolution=RES), Decoder(model, threads=1)
    image_toy, sink_toy = Image(size=RES), ImageSink(size=RES)
    assert port(image_toy.variables["image"])[:5] == port(camera.variables["image"])[:5]
    assert port(sink_toy.variables["image"]) == port(decoder.variables["image"])
    seen = simulate(System([Image("camera", size=RES), decoder], [("camera.image", "decoder.image")]), 0.06, 0.02,
                    batch_size=2, record=["decoder.visual_error"])
    assert np.isfinite(seen.values["decoder.visual_error"]).all()
    shown = simulate(System([Camera(resolution=RES), ImageSink("decoder", size=RES)],
                            [("camera.image", "decoder.image")]), 0.06, 0.02, batch_size=2, record=["decoder.mean"])
    assert (shown.values["decoder.mean"][1:] > 0).all()


def test_the_linear_double_and_the_constant_command_have_the_real_ports():
    """LinearDecoder stands for the Decoder in the brain's tests, and Constant for the brain's commands in the body's:
    the brain-facing ports are the real ones (the prediction is flat in the double: its 'image' is a vector)."""
    from rhi.components.brain import Brain
    from tests.toys import Constant

    real, double = Decoder(tiny_model(), threads=1), LinearDecoder(np.zeros((4, 2)), np.zeros(4), np.zeros(4))
    for name in ("mu", "visual_drive", "visual_error", "visual_stiffness", "visual_variance"):
        assert port(double.variables[name])[:5] == port(real.variables[name])[:5], name
    for name in ("visual_drive", "visual_error", "visual_stiffness"):
        assert double.variables[name].depends_on is not None and "mu" in double.variables[name].depends_on
        assert "mu" in real.variables[name].depends_on
    command, brain = Constant(unit="deg/s"), Brain()
    assert port(command.variables["y"])[:5] + (command.variables["y"].depends_on,) == \
        port(brain.variables["u_shoulder"])[:5] + (brain.variables["u_shoulder"].depends_on,)
