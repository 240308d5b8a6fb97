"""A task's system around a model: the one place a model's components, links and parameters join a task's.

Every task builds its system with :func:`assemble`: the task's components (its world: arms, cameras, stimuli,
decoders), the model's (:func:`model_parts`: :meth:`master.models.Model.parts`, then its brain), then the task's
components after the brain (the body), wired by the task's links and the model's, and given the task's
parameters and the model's (:func:`master.config.sources.model_parameters`; :func:`declared` keeps those the
system's components declare).
"""
from __future__ import annotations

from master import models
from master.cosim import ConfigError, System
from master.decoders.cache import pose_encoder_path
from master.models.base import Scene


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
    (the model's own checkpoint or the shipped one, :func:`master.decoders.cache.pose_encoder_path`)."""
    def make(name: str):
        from components.vision.pose_encoder import PoseEncoder, load_encoder
        return PoseEncoder(load_encoder(pose_encoder_path(kind, config)), name=name,
                           resolution=config["experiment"]["resolution"], threads=threads)
    return make


def model_parts(config: dict, kind: str, threads: int | None = None) -> list:
    """The model's components for decoder slot ``kind``: its parts (a pose encoder, say), then its brain."""
    model = models.of(config)
    return [*model.parts(Scene(config, kind, threads, pose_encoders(config, kind, threads))), model.brain()]


def declared(given: dict, system: System) -> dict:
    """The parameters of ``given`` that a component of ``system`` declares (a task gives every model the same
    sources; a brain, or a body swapped in, takes those it declares)."""
    return {path: value for path, value in given.items() if path.partition(".")[0] in system.components
            and path.partition(".")[2] in system.components[path.partition(".")[0]].variables}
