"""The causal model: each mechanism against a hand computation, the pose encoder's calibration, the wiring
(no simulator position reaches the brain), the population, and --model in the configuration."""
import math

import numpy as np
import pytest
import scipy.linalg
import torch

from rhi.components.brain import body_inference as bi
from rhi.components.brain.causal_brain import CausalBrain
from rhi.components.stimulus import Stimulus
from rhi.components.vision import pose_encoder as pe
from rhi.components.vision.networks import Encoder, preset
from tests.toys import assert_reads_no_simulator_position
from rhi.master.cosim import ConfigError
from rhi.master import models
from rhi.master import config as configuration
from rhi.master.config import protocol
from rhi.master.tasks.illusion import wiring


def normal_log_pdf(x, mean, sd):
    """By hand: log of exp(-(x - m)^2 / (2 s^2)) / (s sqrt(2 pi))."""
    return -((x - mean) ** 2) / (2 * sd * sd) - math.log(sd * math.sqrt(2 * math.pi))


def test_spatial_likelihood_ratio_is_the_hand_computation():
    seen, variance, felt = np.array([[10.0, -3.0]]), np.array([[0.5, 2.0]]), np.array([[1.0, 0.0]])
    coupling, mean, spread = np.array([[4.0, 3.0]]), np.array([[0.0, 1.0]]), np.array([[20.0, 25.0]])
    one = normal_log_pdf(10, 1, math.sqrt(0.5 + 1 + 16)) + normal_log_pdf(-3, 0, math.sqrt(2 + 1 + 9))
    two = normal_log_pdf(10, 0, 20) + normal_log_pdf(-3, 1, 25)
    got = bi.spatial_likelihood_ratio(seen, variance, felt, np.array([1.0]), coupling, mean, spread)
    assert got[0] == pytest.approx(math.exp(one - two), rel=1e-12)  # float64 sums of a few terms


def test_timing_ratio_and_posterior_are_the_hand_computation():
    ratio = bi.timing_likelihood_ratio(np.array([0.1]), 0.2, 0.1, 0.5)
    sd = math.sqrt(0.04 + 0.01)
    assert ratio[0] == pytest.approx(math.exp(normal_log_pdf(0.1, 0, sd)) / 0.5, rel=1e-12)  # rounding only
    assert bi.posterior(np.array([0.2]), np.array([3.0]))[0] == pytest.approx(0.6 / (0.6 + 0.8), rel=1e-15)
    assert bi.posterior(np.array([0.2]), np.array([np.inf]))[0] == 1.0


def test_hazard_update_is_the_markov_chain_solved_by_the_matrix_exponential():
    prior, switching, step = 0.28, 20.0, 0.02
    k_on, k_off = prior / switching, (1 - prior) / switching
    generator = np.array([[-k_off, k_off], [k_on, -k_on]])  # rows: from one cause, from two causes
    start = np.array([0.9, 0.1])
    for steps in (1, 500):
        truth = start @ scipy.linalg.expm(generator * step * steps)
        gamma = np.array([0.9])
        for _ in range(steps):
            gamma = bi.hazard_predict(gamma, prior, switching, step)
        assert gamma[0] == pytest.approx(truth[0], abs=1e-12)  # 500 roundings of ~1e-16 each


def test_half_life_of_the_common_cause_state_is_switching_time_ln2():
    gamma, prior, switching, step = np.array([1.0]), 0.28, 20.0, 0.02
    steps = 0
    while gamma[0] - prior > 0.5 * (1 - prior):
        gamma, steps = bi.hazard_predict(gamma, prior, switching, step), steps + 1
    assert steps * step == pytest.approx(switching * math.log(2), abs=step)  # to the step


def test_gaussian_nll_is_the_hand_formula():
    mean, log_var, target = torch.tensor([[0.1, -0.2]]), torch.tensor([[-1.0, 0.5]]), torch.tensor([[0.3, 0.0]])
    hand = np.mean([0.5 * (-1.0 + 0.2 ** 2 / math.exp(-1.0)), 0.5 * (0.5 + 0.2 ** 2 / math.exp(0.5))])
    assert float(pe.gaussian_nll(mean, log_var, target)) == pytest.approx(hand, rel=1e-6)  # float32


def test_variance_calibration_recovers_a_known_scale_and_then_covers():
    rng = np.random.default_rng(0)
    n, scale = 20000, np.array([4.0, 0.25])
    variance = rng.uniform(0.5, 2.0, (n, 2))
    truth = rng.standard_normal((n, 2)) * np.sqrt(variance * scale)
    fitted = pe.variance_scale(np.zeros((n, 2)), variance, truth)
    # the mean of n chi-square(1) draws has sd sqrt(2/n) = 0.01: 5 sd
    assert fitted == pytest.approx(scale, rel=0.05)
    covered = pe.coverage(np.zeros((n, 2)), variance * fitted, truth)
    for level, fraction in covered.items():  # binomial sd sqrt(p(1-p)/n) <= 0.0036: 5 sd
        assert fraction == pytest.approx([level, level], abs=0.018)


def test_the_shipped_pose_encoders_state_their_calibration():
    for kind in ("conv", "vae"):
        model = pe.load_encoder(f"master/decoders/checkpoints/pose-{kind}-r64.pt")
        for level in ("50", "90"):  # measured on held-out poses when shipped; a stored number, checked for range
            assert all(0 < value < 1 for value in model.metadata[f"coverage_{level}"])


@pytest.fixture(scope="module")
def tiny_causal(tmp_path_factory):
    """A configuration of the causal model at 16 px with an untrained tiny pose encoder."""
    folder = tmp_path_factory.mktemp("pose")
    encoder = Encoder(preset("tiny"), 16)
    path = folder / "pose.pt"
    pe.save_encoder(path, pe.PoseModel(encoder, (147.7, -91.2), (40.0, 50.0), (1.0, 1.0)), preset("tiny"), 16)
    config = configuration.load(overrides={"experiment.resolution": 16, "experiment.steps": 60,
                                           "experiment.trials": 1, "causal.conv_pose_encoder": str(path),
                                           "causal.vae_pose_encoder": str(path)}, model_name="causal")
    return config


def test_the_causal_brain_never_reads_a_simulator_position(tiny_causal):
    from rhi.components.vision.component import Decoder, GenerativeModel
    from rhi.components.body import kinematics
    from rhi.components.vision.networks import build

    model = GenerativeModel(build("conv", "tiny", 16).decoder, kinematics.REST_POSE, (40.0, 50.0), {"kind": "conv"})
    assert_reads_no_simulator_position(wiring.build_system(Decoder(model, threads=1), tiny_causal), CausalBrain())


def test_a_tiny_causal_run_and_its_gamma(tiny_causal):
    from rhi.master.tasks.illusion.runner import batch_outcomes

    config = tiny_causal
    trials = protocol.plan(configuration.merge(config, {"experiment": {"decoders": ["conv"]}}))
    from rhi.components.vision.component import GenerativeModel, Decoder
    from rhi.components.body import kinematics
    from rhi.components.vision.networks import build
    model = GenerativeModel(build("conv", "tiny", 16).decoder, kinematics.REST_POSE, (40.0, 50.0), {"kind": "conv"})
    result = wiring.run_batch(Decoder(model, threads=1), trials, config)
    gamma, timing = result.values["brain.gamma"], result.values["brain.gamma_timing"]
    assert np.all((gamma >= 0) & (gamma <= 1)) and np.all(np.isfinite(result.values["brain.mu"]))
    # Before the first touch (2 s > 60 steps * 0.02 s) gamma_timing sits at each participant's prior exactly.
    brain = CausalBrain()
    brain.instantiate(len(trials))
    for path, value in wiring.parameters(trials, config).items():
        if path.startswith("brain."):
            brain.set(path.partition(".")[2], value)
    brain.initialize()
    assert timing[-1] == pytest.approx(brain.participant["common_cause_prior"], rel=1e-12)


def test_participants_are_seeded_and_drawn_around_the_medians():
    seeds = np.arange(4000)
    medians = {"common_cause_prior": np.full(4000, 0.28), "switching_time": np.full(4000, 20.0),
               "timing_noise_sd": np.full(4000, 0.1)}
    spreads = {"timing_noise_sd": 0.3, "switching_time": 0.3, "coupling_scale": 0.2}
    values, _ = bi.participants(seeds, medians, spreads, np.full(4000, 20.0))
    again, _ = bi.participants(seeds[:3], {k: v[:3] for k, v in medians.items()}, spreads, np.full(3, 20.0))
    assert all(np.array_equal(values[k][:3], again[k]) for k in values)
    # log-normal median = the median; sd of a sample median ~ 1.25 s / sqrt(n) of the log: 0.006, 5 sd
    assert np.median(values["switching_time"]) == pytest.approx(20.0, rel=0.03)
    assert np.mean(values["common_cause_prior"]) == pytest.approx(0.28, abs=0.01)  # Beta sd 0.098/sqrt(n), 6 sd


def test_stimulation_stops_at_stop_time():
    stimulus = Stimulus()
    stimulus.instantiate(1)
    stimulus.set("stop_time", np.array([5.0]))
    stimulus.setup_experiment(0.0)
    stimulus.initialize()
    for k in range(500):
        stimulus.step(k * 0.02, 0.02)
    assert stimulus.values["visual_time"][0] == 4.0  # touches at 2 and 4 s, none at 6, 8, 10
    assert stimulus.values["tactile_time"][0] < 4.1


def test_models_in_the_configuration():
    assert configuration.load(model_name="paper") == configuration.load()
    causal_config = configuration.load(model_name="causal")
    assert models.of(causal_config).name == "causal" and "causal" in causal_config
    with pytest.raises(ConfigError, match="model 'nope' is unknown"):
        configuration.load(model_name="nope")
    with pytest.raises(ConfigError, match="unknown config key causal"):
        configuration.load(overrides={"causal.pixel_weight": 1.0})  # causal keys exist only in the causal model


def test_a_sweep_file_names_its_model(tmp_path):
    from rhi.master.sweeps import plan as sweeps

    path = tmp_path / "s.toml"
    path.write_text('[experiment]\ndecoders = ["conv"]\n[sweep]\nmodel = "causal"\n[sweep.grid]\n'
                    '"causal.switching_time" = [10.0, 40.0]\n')
    sweep = sweeps.load(path)
    assert [c["causal"]["switching_time"] for c in sweep.configs] == [10.0, 40.0]
    assert all(models.of(c).name == "causal" for c in sweep.configs)
    with pytest.raises(ConfigError, match="unknown config key causal"):  # the paper's model has no causal keys
        sweeps.load(path, model="paper")
    path.write_text('[sweep]\nmodel = "other"\n')
    with pytest.raises(ConfigError, match="sweep.model: model 'other' is unknown; choose one of paper, causal"):
        sweeps.load(path)
