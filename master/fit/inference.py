"""Neural posterior estimation with the ``sbi`` package: the prior in the inference space, training one
amortised estimator on the simulated participants, saving and loading it, sampling a participant's posterior.

The estimator is a conditional normalising flow (``fit.estimator``: a masked autoregressive flow by default,
Papamakarios, Pavlakou & Murray 2017, as ``sbi`` builds it), trained by maximum likelihood on (parameters,
summary statistics) pairs drawn from the prior and the simulator (NPE: Papamakarios & Murray 2016; Greenberg,
Nonnenmacher & Macke 2019). Trained once, it gives the posterior of any participant of the same design in one
pass of the flow (amortisation). Same seed, same threads, same data: the same weights and the same samples.

``fit.estimator.ensemble = K`` trains K estimators from K seeds on the same set, and the posterior is their
equal-weight mixture (sbi's EnsemblePosterior): an ensemble of NPE posteriors is more conservative than any one
of them where a single estimator is overconfident (Hermans et al. 2022, "A trust crisis in simulation-based
inference? Your posterior approximations can be unfaithful", TMLR; Lakshminarayanan, Pritzel & Blundell 2017).
"""
from __future__ import annotations

import math
import time

import numpy as np

from rhi.master.cosim import SimulationError
from rhi.master.fit.plan import Parameter


class TrainingError(SimulationError):
    """The estimator's training failed during the work (its loss is not finite): one line, exit status 1, as a
    failed run (docs/configuration.md); the simulations are kept, so the same command resumes."""

    def __init__(self, reason: str):
        RuntimeError.__init__(self, reason)
        self.component, self.time, self.reason, self.status, self.trials = "estimator", 0.0, reason, "error", ()

    def __reduce__(self):
        return type(self), (self.reason,)


def unusable(estimator) -> str | None:
    """Why a built estimator cannot be sampled, or None: a weight that is NaN or infinite (its flow gives NaN
    samples, which sbi rejects as outside the prior forever)."""
    for name, tensor in estimator.state_dict().items():
        if tensor.is_floating_point() and not bool(tensor.isfinite().all()):
            return f"its weight {name} holds NaN or infinity"
    return None


def torch_prior(parameters: list[Parameter]):
    """The prior in the inference space as a torch distribution over (parameters,) vectors (sbi's
    MultipleIndependent of one-dimensional uniforms, normals and truncated normals)."""
    import torch
    from sbi.utils import MultipleIndependent

    parts = []
    for parameter in parameters:
        low, high = inference_bounds(parameter)
        if parameter.prior == "normal":
            if math.isfinite(low) or math.isfinite(high):
                parts.append(TruncatedNormal(parameter.mean, parameter.sd, low, high))
            else:
                parts.append(torch.distributions.Normal(torch.tensor([parameter.mean]), torch.tensor([parameter.sd])))
        else:
            parts.append(torch.distributions.Uniform(torch.tensor([low]), torch.tensor([high])))
    if len(parts) == 1:  # sbi's MultipleIndependent combines two or more
        return torch.distributions.Independent(parts[0], 1)
    return MultipleIndependent(parts, validate_args=False)


def inference_bounds(parameter: Parameter) -> tuple[float, float]:
    """The parameter's bounds in the inference space (-inf, inf where it has none)."""
    return tuple(float(parameter.to_inference(bound)) for bound in (parameter.low, parameter.high))


def unconstraining(parameters: list[Parameter]):
    """``fit.estimator.space = "unconstrained"``: the bijection of the inference space onto the whole of R^d.

    Each parameter's support in the inference space (an interval, a half-line or the line) is mapped onto the
    line by the inverse of torch's ``biject_to`` (a logit for an interval, a log for a half-line): the transform
    to unconstrained space that Stan and sbi's MCMC use for bounded parameters. A flow has no sharp edges;
    trained on a bounded support it puts mass beyond the bounds, which sbi rejects ("leakage"), and it draws a
    posterior that fills the support, the prior itself included, as a bump narrower than it. In the unconstrained
    space the bounds lie at infinity. Returns a torch transform over (..., parameters) tensors."""
    from torch.distributions import biject_to, constraints
    from torch.distributions.transforms import CatTransform, IndependentTransform

    parts = []
    for parameter in parameters:
        low, high = inference_bounds(parameter)
        bounded_below, bounded_above = math.isfinite(low), math.isfinite(high)
        if bounded_below and bounded_above:
            support = constraints.interval(low, high)
        elif bounded_below:
            support = constraints.greater_than(low)
        elif bounded_above:
            support = constraints.less_than(high)
        else:
            support = constraints.real
        parts.append(biject_to(support).inv)
    return IndependentTransform(CatTransform(parts, dim=-1, lengths=[1] * len(parts)), 1)


def flow_prior(parameters: list[Parameter], settings: dict):
    """The prior over the space the flow is trained in: :func:`torch_prior`, or its image under
    :func:`unconstraining` (a torch TransformedDistribution, the Jacobian in its density)."""
    from torch.distributions import TransformedDistribution

    prior = torch_prior(parameters)
    return TransformedDistribution(prior, [unconstraining(parameters)]) if settings["space"] == "unconstrained" else prior


def to_flow(parameters: list[Parameter], settings: dict, theta: np.ndarray):
    """(rows, parameters) values of the inference space as a float32 tensor of the flow's space."""
    import torch

    theta = torch.as_tensor(np.asarray(theta), dtype=torch.float32)
    return unconstraining(parameters)(theta) if settings["space"] == "unconstrained" else theta


def truncated_normal_class():
    """The class of :func:`TruncatedNormal`'s distributions, defined when called (torch is imported only then)."""
    import torch
    from torch.distributions import constraints

    class _TruncatedNormal(torch.distributions.Distribution):
        """A normal of ``mean`` and ``sd`` restricted to [low, high], one-dimensional (shape (1,))."""

        arg_constraints: dict = {}
        has_rsample = False

        def __init__(self, mean, sd, low, high):
            self.mean_, self.sd_ = torch.tensor([float(mean)]), torch.tensor([float(sd)])
            self.low, self.high = torch.tensor([float(low)]), torch.tensor([float(high)])
            normal = torch.distributions.Normal(self.mean_, self.sd_)
            self.normal = normal
            self.cdf_low, self.cdf_high = normal.cdf(self.low), normal.cdf(self.high)
            super().__init__(batch_shape=torch.Size([1]), validate_args=False)

        @property
        def support(self):
            return constraints.interval(self.low, self.high)

        def sample(self, sample_shape=torch.Size()):
            uniform = torch.rand(torch.Size(sample_shape) + self.batch_shape)
            probability = self.cdf_low + uniform * (self.cdf_high - self.cdf_low)
            return torch.clamp(self.mean_ + self.sd_ * torch.special.ndtri(probability), self.low, self.high)

        def log_prob(self, value):
            inside = (value >= self.low) & (value <= self.high)
            density = self.normal.log_prob(value) - torch.log(self.cdf_high - self.cdf_low)
            return torch.where(inside, density, torch.full_like(density, -math.inf))

    return _TruncatedNormal


def TruncatedNormal(mean, sd, low, high):  # noqa: N802: a distribution's constructor
    """A normal restricted to [low, high], one-dimensional, as a torch distribution.

    Parameters
    ----------
    mean, sd, low, high : float
        The normal's mean and sd and the bounds, in the inference space's units.

    Returns
    -------
    torch.distributions.Distribution
        Batch shape (1,); ``sample`` by the inverse distribution function, ``log_prob`` -inf outside the bounds.
    """
    return truncated_normal_class()(mean, sd, low, high)


def statistics_scale(settings: dict, training: np.ndarray):
    """``fit.estimator.statistics``: the map the statistics go through before the estimator sees them, fitted on
    the training statistics ``training`` (participants, statistics); a function of (..., statistics) arrays.

    "z-score": none (sbi z-scores each statistic by the training set's mean and sd, as always).
    "normal-scores": each statistic by its rank-based inverse normal transform on the training set (Beasley,
    Erickson & Allison 2009, Behav. Genet. 39:580; Bliss's rankits): the k-th smallest of n training values goes
    to Phi^-1((k - 1/2) / n), a value between two training values by linear interpolation, a value beyond them to
    the nearest end. Monotone, so it keeps every statistic's information inside the training range; it takes
    statistics that span decades to the normal's scale, where z-scoring leaves most of them within a small
    fraction of one sd of each other."""
    if settings["statistics"] == "z-score":
        return lambda x: np.asarray(x, dtype=float)
    from scipy import stats

    ordered = np.sort(np.asarray(training, dtype=float), axis=0)
    scores = stats.norm.ppf((np.arange(1, len(ordered) + 1) - 0.5) / len(ordered))

    def normal_scores(x):
        x = np.asarray(x, dtype=float)
        if x.shape[-1] != ordered.shape[1]:
            raise ValueError(f"{x.shape[-1]} statistics given to an estimator trained on {ordered.shape[1]}")
        return np.stack([np.interp(x[..., d], ordered[:, d], scores) for d in range(ordered.shape[1])], axis=-1)
    return normal_scores


def flow_pairs(parameters: list[Parameter], settings: dict, theta: np.ndarray, x: np.ndarray):
    """The training pairs as the estimator sees them: theta in the flow's space, x on the statistics' scale
    (both float32 tensors)."""
    import torch

    return to_flow(parameters, settings, theta), torch.as_tensor(statistics_scale(settings, x)(x), dtype=torch.float32)


def builder(settings: dict):
    """sbi's density-estimator builder for ``fit.estimator``'s settings."""
    from sbi.neural_nets import posterior_nn

    return posterior_nn(model=settings["density"], hidden_features=settings["hidden_features"],
                        num_transforms=settings["transforms"])


def train(parameters: list[Parameter], theta: np.ndarray, x: np.ndarray, settings: dict, seed: int) -> tuple:
    """Train the estimator on (theta, x) (rows: simulated participants; theta in the inference space).

    Returns (the trained estimator, a summary: epochs, best validation loss, seconds)."""
    import torch
    from sbi.inference import NPE

    torch.set_num_threads(settings["threads"])
    torch.manual_seed(seed)
    began = time.perf_counter()
    inference = NPE(prior=flow_prior(parameters, settings), density_estimator=builder(settings),
                    show_progress_bars=False, tracker=NoTracker())
    inference.append_simulations(*flow_pairs(parameters, settings, theta, x))
    try:
        estimator = inference.train(training_batch_size=settings["batch_size"],
                                    learning_rate=settings["learning_rate"], max_num_epochs=settings["max_epochs"],
                                    show_train_summary=False)
    except ValueError as error:
        if "NaN/Inf" not in str(error):  # sbi's assert_all_finite on the loss
            raise
        estimator = None
    summary = inference.summary
    if estimator is None or unusable(estimator) or not math.isfinite(float(summary["best_validation_loss"][-1])):
        raise TrainingError(f"training the estimator failed: its loss became NaN or infinite (fit.estimator."
                            f"learning_rate = {settings['learning_rate']:g}, batch_size = {settings['batch_size']}); "
                            "lower fit.estimator.learning_rate. The simulations are kept: the same command resumes")
    return estimator, {"epochs": int(summary["epochs_trained"][-1]),
                       "best_validation_loss": float(summary["best_validation_loss"][-1]),
                       "seconds": round(time.perf_counter() - began, 3), "training_participants": int(len(theta))}


class NoTracker:
    """sbi's training log kept nowhere (its default writes TensorBoard files under the working folder)."""

    log_dir = None

    def log_metric(self, name, value, step=None):
        """Ignore a metric."""
        pass

    def log_metrics(self, metrics, step=None):
        """Ignore metrics."""
        pass

    def log_params(self, params):
        """Ignore parameters."""
        pass

    def add_figure(self, name, figure, step=None):
        """Ignore a figure."""
        pass

    def flush(self):
        """Nothing to write."""
        pass


def rebuild(parameters: list[Parameter], theta: np.ndarray, x: np.ndarray, settings: dict, state: dict, seed: int):
    """The estimator of ``state`` (its saved weights): built on the same training set (which fixes the
    z-scoring and the shapes), then the weights loaded."""
    import torch

    torch.set_num_threads(settings["threads"])
    torch.manual_seed(seed)
    estimator = builder(settings)(*flow_pairs(parameters, settings, theta, x))
    estimator.load_state_dict(state)
    return estimator.eval()


def posterior(parameters: list[Parameter], estimators: list, settings: dict, training: np.ndarray):
    """The posterior of one trained estimator, or the equal-weight mixture of an ensemble's, over the flow's space;
    ``training``: the statistics it was trained on, which fix the statistics' scale (:func:`sample` applies it)."""
    from sbi.inference.posteriors import DirectPosterior, EnsemblePosterior

    prior = flow_prior(parameters, settings)
    members = [DirectPosterior(posterior_estimator=estimator, prior=prior) for estimator in estimators]
    result = members[0] if len(members) == 1 else EnsemblePosterior(members)
    result.statistics_scale = statistics_scale(settings, training)
    return result


def sample(posterior_, x: np.ndarray, count: int, seed: int) -> np.ndarray:
    """(count, parameters) samples of the posterior of :func:`posterior` given one participant's statistics ``x``
    (their own units), in the inference space; the same seed, the same samples."""
    import torch

    torch.manual_seed(seed)
    scaled = posterior_.statistics_scale(np.asarray(x)[None])
    with torch.no_grad():
        samples = posterior_.sample((count,), x=torch.as_tensor(scaled, dtype=torch.float32), show_progress_bars=False)
    prior = posterior_.prior  # the flow's space: back to the inference space where it is unconstrained
    if isinstance(prior, torch.distributions.TransformedDistribution):
        samples = torch.distributions.transforms.ComposeTransform(prior.transforms).inv(samples)
    return samples.double().numpy()
