"""A task's system around a model: the one place a model's components, links and parameters join a task's.

A task describes its system as data, a :class:`Scenario`: its world (arms, cameras, stimuli, decoders), its
components after the brain (the body), its links and what it records. :func:`build` is the one function that
makes a system of a scenario and the configuration's model: the world, the model's parts and brain
(:func:`model_parts`), the body, wired by the task's links and then the model's (:func:`assemble`);
:func:`run` simulates it at the experiment's step for a batch, given the task's parameters and the model's
(:func:`rhi.master.config.sources.model_parameters`; :func:`declared` keeps those the system's components declare).
"""
from __future__ import annotations

from dataclasses import dataclass

from rhi.master import config as configuration
from rhi.master import models
from rhi.master.cosim import ConfigError, System, simulate
from rhi.master.decoders.cache import pose_encoder_path
from rhi.master.models.base import PartsKit


@dataclass(frozen=True)
class Scenario:
    """A task's system as data, around whichever model the configuration names (:func:`build`).

    Attributes
    ----------
    world : tuple of Component
        The task's components before the model's, in step order (the model's parts read their outputs).
    body : tuple of Component
        The task's components after the brain, in step order (they receive its action).
    links : tuple of (str, str)
        The task's candidate ``("component.output", "component.input")`` links, in order; the model's follow.
    record : tuple of str
        The ``component.variable`` paths recorded at every step.
    kind : str
        The decoder slot (``"conv"``, ``"vae"``) whose pose encoder the model's parts use.
    threads : int or None
        Torch threads of the model's parts (None: torch's default).
    pixel_term : tuple of str
        The names of world components that only give the brain the decoder's pixel term (``visual_*``): left
        out, with what they would record, when the model reads no pixel term in any trial (:func:`reads_pixels`).
    seen_image : str
        The output that carries the image the participant sees: the camera's, or a screen's that hides the rubber
        arm for part of a trial. The model's links from ``camera.image`` read it instead.
    """

    world: tuple
    body: tuple
    links: tuple
    record: tuple
    kind: str
    threads: int | None = None
    pixel_term: tuple = ()
    seen_image: str = "camera.image"


def reads_pixels(config: dict, trials=()) -> bool:
    """Whether the model's brain reads the decoder's pixel term (:meth:`rhi.master.models.Model.reads_pixels`) in the
    configuration, or in any of ``trials`` with values of their own (``Trial.overrides``, a fit's batch)."""
    model = models.of(config)
    own = {trial.overrides for trial in trials if getattr(trial, "overrides", ())}
    return model.reads_pixels(config) or any(
        model.reads_pixels(configuration.merge(config, configuration.nest(dict(values)))) for values in own)


def build(scenario: Scenario, config: dict, trials=()) -> System:
    """The system of ``scenario`` with the configuration's model: world, the model's parts and brain, body (the
    scenario's pixel-term components only when the brain reads the term in one of ``trials``)."""
    left_out = () if reads_pixels(config, trials) else scenario.pixel_term
    parts = [*(part for part in scenario.world if part.name not in left_out),
             *model_parts(config, scenario.kind, scenario.threads), *scenario.body]
    model_links = [(scenario.seen_image if source == "camera.image" else source, target)
                   for source, target in models.of(config).links]
    return assemble(parts, [*scenario.links, *model_links])


def run(scenario: Scenario, config: dict, parameters, batch_size: int, progress=None, trials=()):
    """Simulate ``scenario`` (:func:`build`) for the experiment's steps, ``batch_size`` trials in lockstep.

    Parameters
    ----------
    scenario : Scenario
    config : dict
        The configuration: its model, and ``experiment.steps``, ``step_size`` (s) and ``scheme``.
    parameters : callable
        ``parameters(system) -> dict`` of ``component.variable`` values, scalars or (batch_size, ...) arrays.
    batch_size : int
        Trials in lockstep, B.
    progress : callable, optional
        ``progress(done, total)`` after each step.
    trials : sequence of Trial, optional
        The batch's trials, for :func:`build`.

    Returns
    -------
    rhi.master.cosim.Result
        ``times`` (T,) s and ``values[path]`` (T, B, ...) of ``scenario.record`` (less the components left out;
        their parameters are not given).
    """
    experiment = config["experiment"]
    system = build(scenario, config, trials)
    left_out = set(scenario.pixel_term) - set(system.components)
    given = {path: value for path, value in parameters(system).items() if path.partition(".")[0] not in left_out}
    record = [path for path in scenario.record if path.partition(".")[0] not in left_out]
    return simulate(system, stop_time=experiment["steps"] * experiment["step_size"],
                    step_size=experiment["step_size"], scheme=experiment["scheme"], batch_size=batch_size,
                    parameters=given, record=record, progress=progress)


def assemble(parts: list, links) -> System:
    """The system of ``parts`` (in step order) and the ``links`` whose ends it has.

    A link is kept when both of its components are in the system and the target declares the input: a brain
    that reads no simulator position declares no input for one, and so gets none. A link from a component that
    is there but lacks the output is an error (a misspelt link).

    Parameters
    ----------
    parts : list of Component
        The system's components in Gauss-Seidel order.
    links : iterable of (str, str)
        Candidate ``("component.output", "component.input")`` connections, in order.

    Returns
    -------
    System
    """
    present = {part.name: part for part in parts}
    kept = []
    for source, target in links:
        (source_name, output), (target_name, variable) = source.split("."), target.split(".")
        if source_name not in present or target_name not in present or variable not in present[target_name].variables:
            continue
        if output not in present[source_name].variables:
            raise ConfigError(f"link {source} -> {target}: {source_name} has no output {output}")
        if (source, target) not in kept:
            kept.append((source, target))
    return System(parts, kept)


def pose_encoders(config: dict, kind: str, threads: int | None):
    """``make(name)``: a pose encoder component reading decoder slot ``kind``'s image at the run's resolution
    (the model's own checkpoint or the shipped one, :func:`rhi.master.decoders.cache.pose_encoder_path`)."""
    def make(name: str):
        from rhi.components.vision.pose_encoder import PoseEncoder, load_encoder
        return PoseEncoder(load_encoder(pose_encoder_path(kind, config)), name=name,
                           resolution=config["experiment"]["resolution"], threads=threads)
    return make


def model_parts(config: dict, kind: str, threads: int | None = None) -> list:
    """The model's components for decoder slot ``kind``: its parts (a pose encoder, say), then its brain."""
    model = models.of(config)
    return [*model.parts(PartsKit(config, kind, threads, pose_encoders(config, kind, threads))), model.brain()]


def declared(given: dict, system: System) -> dict:
    """The parameters of ``given`` that a component of ``system`` declares (a task gives every model the same
    sources; a brain, or a body swapped in, takes those it declares)."""
    return {path: value for path, value in given.items() if path.partition(".")[0] in system.components
            and path.partition(".")[2] in system.components[path.partition(".")[0]].variables}
