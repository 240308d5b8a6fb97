"""The model contract: what a model declares, and what a task gives it to build its part of a system."""
from __future__ import annotations

import copy
import re
import tomllib
from dataclasses import dataclass
from importlib import resources
from typing import Any, Callable

import numpy as np

from rhi.components.component import Component
from rhi.master.cosim import ConfigError

_PLAIN_KEY = re.compile(r"[a-z_]+\.[a-z_0-9]+")
_PATH = re.compile(r"[a-z_][a-z_0-9]*\.[a-z_][a-z_0-9]*")


def shipped_settings(file: str) -> dict:
    """A settings file shipped beside the built-in models (``master/models/FILE``)."""
    with resources.files("rhi.master.models").joinpath(file).open("rb") as handle:
        return tomllib.load(handle)


def config_key(source: str) -> str | None:
    """The configuration key a plain parameter source names (``"brain.gamma0"``), else None (a ``derived:``
    or ``per trial:`` source, or a constructor's)."""
    return source if _PLAIN_KEY.fullmatch(source) else None


@dataclass(frozen=True)
class PartsKit:
    """What a task hands a model to build its components (:meth:`Model.parts`): the configuration, the decoder slot,
    torch threads and a pose encoder maker (not the task's system: that is a
    :class:`rhi.master.tasks.scene.Scenario`).

    Attributes
    ----------
    config : dict
        The run's configuration.
    decoder_kind : str
        The decoder slot of this batch (``"conv"`` or ``"vae"``): it picks the pose encoder.
    threads : int or None
        torch threads for a network component (None: torch's default).
    pose_encoder : callable
        ``pose_encoder(name)``: a pose encoder component named ``name`` reading the camera's image of this
        decoder slot (:class:`rhi.components.vision.pose_encoder.PoseEncoder`), built by the task.
    """

    config: dict
    decoder_kind: str
    threads: int | None
    pose_encoder: Callable[[str], Component]


@dataclass(frozen=True)
class TrialValues:
    """What a model's parameters are computed from, for one lockstep batch of B trials.

    Attributes
    ----------
    config : dict
        The run's configuration.
    seeds : numpy.ndarray
        (B,) int64: each trial's seed.
    value : callable
        ``value("table.key")``: the key's value for these trials, a scalar, or a (B,) array where the trials
        carry their own values (a sweep's or a fit's batch of several configurations).
    rest_pose : tuple of float
        (2,) deg: the arm's rest pose, the centre of the decoders' training ranges.
    half_ranges : tuple of float
        (2,) deg: the half widths of the decoders' training ranges per joint.
    """

    config: dict
    seeds: np.ndarray
    value: Callable[[str], Any]
    rest_pose: tuple
    half_ranges: tuple


class Model:
    """A model of the agent, declared once and run by every task.

    Subclass it, set the class attributes and :meth:`brain`, and override the methods whose defaults do not fit.
    ``examples/my_model.py`` is a whole one.

    Attributes
    ----------
    name : str
        What ``[model] name`` records (a built-in's name, or the user's).
    summary : str
        One line on what the model is, for ``--help`` and the run's provenance.
    settings_file : str
        A TOML file beside the model's module merged over the defaults (its own tables, such as
        ``[causal]``, and the defaults' keys it changes); "" for none.
    own_settings : dict
        The same as a dict, for a model in one file (merged over the settings file's).
    parameter_sources : dict
        The brain's parameters: ``"brain.variable"`` -> where its value comes from: a configuration key
        (``"brain.gamma0"``, passed as is, per trial where trials differ), ``"derived: ..."`` (computed by
        :meth:`parameters`) or ``"per trial: ..."`` (also computed there).
    batchable : tuple of str
        Configuration keys besides the plain sources that may differ between the trials of one batch (a key a
        derived parameter is computed from per trial).
    links : tuple of (str, str)
        Connections the model adds to every task's system, ``("component.output", "component.input")``; a
        link whose ends are not in a task's system is left out.
    record : tuple of str
        Paths recorded besides the task's.
    measures : dict
        Columns of trials.csv (and a sweep's or a fit's trial outcomes) the model adds: ``"name_unit"`` ->
        a recorded path (one of ``record``) of one value per trial and step.
    sees_pose : bool
        Whether the brain reads the seen arm's pose through a pose encoder of the camera's image (it then
        needs the camera to see the arm, and a pose encoder at the run's resolution).
    pose_encoder_key : str
        The configuration key naming the pose encoder checkpoint of decoder slot ``{kind}`` (e.g.
        ``"causal.{kind}_pose_encoder"``); "" or an empty value: the shipped one.
    pose_encoder_stem : str
        The shipped pose encoder's name of decoder slot ``{kind}`` without ``-rRES.pt``, in
        master/decoders/checkpoints (:func:`rhi.master.decoders.cache.shipped_pose_encoder`): ``"pose-{kind}"``, the
        causal model's; a model trained over other poses names its own.
    source : str
        Set by the registry: "" for a built-in model, else the spec it was loaded from.
    """

    name: str = ""
    summary: str = ""
    settings_file: str = ""
    own_settings: dict = {}
    parameter_sources: dict = {}
    batchable: tuple = ()
    links: tuple = ()
    record: tuple = ()
    measures: dict = {}
    sees_pose: bool = False
    pose_encoder_key: str = ""
    pose_encoder_stem: str = "pose-{kind}"
    source: str = ""

    def brain(self) -> Component:
        """A new brain component, named ``brain``."""
        raise NotImplementedError(f"model {self.name!r} defines no brain()")

    def settings(self) -> dict:
        """The keys merged over the defaults: the settings file's, and ``[model]`` naming the model (its
        ``source`` too when it is not built in). The defaults are the paper's model: its file is empty, and a
        configuration with no ``[model]`` runs it (:func:`rhi.master.models.of`)."""
        given = {}
        if self.settings_file:
            given = shipped_settings(self.settings_file)
        given = {**given, **copy.deepcopy(self.own_settings)}
        if not given and not self.source:
            return {}
        return {**given, "model": {**given.get("model", {}), "name": self.name,
                                   **({"source": self.source} if self.source else {})}}

    def parts(self, kit: PartsKit) -> list[Component]:
        """Components the model adds to a task's system (besides its brain), in step order before the brain."""
        return [kit.pose_encoder("pose_encoder")] if self.sees_pose else []

    def parameters(self, trials: TrialValues) -> dict:
        """The brain's parameters for one batch: every plain source's value (per trial where trials differ).
        A model with ``derived:`` or ``per trial:`` sources extends this."""
        return {path: trials.value(key) for path, key in ((p, config_key(s)) for p, s in self.parameter_sources.items())
                if key is not None}

    def reach_attractor(self, config: dict) -> str:
        """The goal's term in the reach when ``reach.attractor = "auto"``: ``"pixels"`` (a goal decoder, the
        released agent's) or ``"body"`` (a goal pose encoder and attractor in joint angles)."""
        return "body" if self.sees_pose else "pixels"

    def reads_pixels(self, config: dict) -> bool:
        """Whether the brain reads the decoder's pixel term (``visual_*``) of the camera's image."""
        return True

    def pose_encoder_file(self, kind: str, config: dict) -> str:
        """The pose encoder checkpoint this model reads decoder slot ``kind``'s image with (the value of
        :attr:`pose_encoder_key`); "" for the shipped one at the run's resolution."""
        if not self.pose_encoder_key:
            return ""
        table, _, key = self.pose_encoder_key.format(kind=kind).partition(".")
        return config.get(table, {}).get(key) or ""

    def trials_per_point(self, config: dict) -> int | None:
        """Trials per point of a phenomenon's sweep (``rhi phenomenon``): None for the sweep file's own; a model
        of a population gives one simulated participant a trial."""
        return None

    def check(self) -> None:
        """ConfigError naming the first declaration that does not hold: a name, the brain, its parameter
        sources (each a parameter the brain declares) and links (``component.variable`` pairs)."""
        where = f"model {self.source or self.name!r}"
        if not isinstance(self.name, str) or not re.fullmatch(r"[a-z][a-z0-9_-]*", self.name):
            raise ConfigError(f"{where}: name must be lower-case letters, digits, '-' or '_', got {self.name!r}")
        for attribute in ("own_settings", "parameter_sources", "measures"):
            if not isinstance(getattr(self, attribute), dict):
                raise ConfigError(f"{where}: {attribute} must be a dict, got {type(getattr(self, attribute)).__name__}")
        if not isinstance(self.own_settings.get("model", {}), dict):
            raise ConfigError(f"{where}: own_settings' model must be a table (a dict), got "
                              f"{self.own_settings['model']!r}")
        if not (isinstance(self.record, (tuple, list)) and all(isinstance(p, str) and "." in p for p in self.record)):
            raise ConfigError(f"{where}: record must be a tuple of 'component.variable' paths, got {self.record!r}")
        for column, path in self.measures.items():
            if not isinstance(column, str) or path not in self.record:
                raise ConfigError(f"{where}: measures[{column!r}] = {path!r}: give a column name and a path it "
                                  f"records (one of record: {', '.join(self.record) or 'none'})")
        try:
            brain = self.brain()
        except Exception as error:  # noqa: BLE001: a user's model; say what went wrong in one line
            raise ConfigError(f"{where}: brain() failed: {type(error).__name__}: {error}") from None
        if not isinstance(brain, Component) or brain.name != "brain":
            raise ConfigError(f"{where}: brain() must return a component named 'brain'")
        for path, source in self.parameter_sources.items():
            component, _, variable = path.partition(".")
            if component != "brain" or variable not in brain.variables \
                    or brain.variables[variable].causality != "parameter":
                raise ConfigError(f"{where}: parameter_sources names {path}, not a parameter its brain declares")
            if not isinstance(source, str) or not (config_key(source) or source.startswith(("derived:", "per trial:"))):
                raise ConfigError(f"{where}: parameter_sources[{path!r}] = {source!r}: give a table.key, "
                                  "'derived: ...' or 'per trial: ...'")
        for link in self.links:
            if not (isinstance(link, tuple) and len(link) == 2 and all(isinstance(p, str) and _PATH.fullmatch(p)
                                                                       for p in link)):
                raise ConfigError(f"{where}: links must be ('component.output', 'component.input') pairs, got {link!r}")
