"""Models of the agent, as registered objects: ``paper``, ``causal``, ``ownership``, and any a user brings.

A model is a :class:`Model`: it names its brain, the components it adds to a task's system (a pose
encoder, say), the connections it adds (as data), the parameter sources it adds, and what it records.
Every task (the tasks) assembles its system from a model through :func:`rhi.master.tasks.scene.assemble`,
so a model written once runs in ``rhi experiment``, ``sweep``, ``phenomenon``, ``fit``, ``reach`` and
``export-agent`` with no other change.

Names a model may go by, resolved by :func:`get`:

- a built-in name, ``paper``, ``causal`` or ``ownership`` (:data:`BUILT_IN`);
- a Python entry point in the group ``rhi.models`` (``[project.entry-points."rhi.models"]`` in a package's
  pyproject.toml: ``name = "package.module:Class"``);
- ``path/to/file.py:Class`` or ``package.module:Class``: a user's model in one file
  (``examples/my_model.py``).

A configuration records which model it runs in its ``[model]`` table (``name``, and ``source`` for a model
that is not built in), so that worker processes resolve the same model: :func:`of`.

Example::

    from rhi.master import models
    model = models.get("examples/my_model.py:FixedGamma")
    config = configuration.load(model_name="examples/my_model.py:FixedGamma")
    assert models.of(config).name == model.name
"""
from __future__ import annotations

from importlib import metadata

from rhi.master.cosim import ConfigError
from rhi.master.models.base import Model
from rhi.master.runtime.plugins import load_object

__all__ = ["Model", "BUILT_IN", "ENTRY_POINT_GROUP", "get", "checked", "of", "names", "described", "spec_of"]

BUILT_IN = {"paper": "rhi.master.models.paper:PaperModel", "causal": "rhi.master.models.causal:CausalModel",
            "ownership": "rhi.master.models.ownership:OwnershipModel"}
ENTRY_POINT_GROUP = "rhi.models"
_LOADED: dict[str, Model] = {}  # spec -> the model object, once per process


def names() -> tuple[str, ...]:
    """Every model known by name here: the built-in ones, then the entry points'."""
    found = dict(BUILT_IN)
    for point in metadata.entry_points(group=ENTRY_POINT_GROUP):
        found.setdefault(point.name, point.value)
    return tuple(found)


def spec_of(name: str) -> str:
    """The ``module:Class`` or ``file.py:Class`` that a model's name stands for (a spec stands for itself)."""
    if name in BUILT_IN:
        return BUILT_IN[name]
    for point in metadata.entry_points(group=ENTRY_POINT_GROUP):
        if point.name == name:
            return point.value
    if ":" in name:
        return name
    raise ConfigError(f"model {name!r} is unknown; choose one of {', '.join(names())}, or give "
                      "path/to/file.py:Class or package.module:Class")


def get(name: str) -> Model:
    """The model ``name`` (a built-in name, an entry point's name, ``file.py:Class`` or ``module:Class``), checked.

    Raises
    ------
    ConfigError
        One line naming what is wrong: an unknown name, a file or class that is not there, a class that is not
        a :class:`Model`, or a model whose declarations do not hold (:meth:`Model.check`).
    """
    if not isinstance(name, str) or not name:
        raise ConfigError(f"model must be a name or path/to/file.py:Class, got {name!r}")
    spec = spec_of(name)
    if spec not in _LOADED:
        model = _load(spec)
        model.source = "" if spec in BUILT_IN.values() else spec  # a built-in, however it was named
        model.check()
        _LOADED[spec] = model
    return _LOADED[spec]


def checked(name, where: str) -> Model:
    """:func:`get`, its error prefixed with the key that named the model (``sweep.model``)."""
    try:
        return get(name)
    except ConfigError as error:
        raise ConfigError(f"{where}: {error}") from None


def described() -> str:
    """The models in words, for ``--model``'s help: each built-in name with its summary, each entry point's name
    with what it stands for (named, never imported: a broken plug-in breaks only a run that uses it), and how to
    give one's own."""
    return "; ".join(f"{name} = {get(name).summary}" if name in BUILT_IN else f"{name} = {spec_of(name)}"
                     for name in names()) + "; or path/to/file.py:Class, a model of one's own (examples/my_model.py)"


def of(config: dict) -> Model:
    """The model a configuration runs: its ``[model]`` table's ``source`` (a user's) or ``name``; ``paper`` when
    it has none (the defaults are the paper's model)."""
    table = config.get("model", {})
    return get(table.get("source") or table.get("name", "paper"))


def _load(spec: str) -> Model:
    model = load_object(spec, "model")
    if not isinstance(model, Model):
        raise ConfigError(f"model {spec!r}: {spec.rpartition(':')[2]} is not a rhi.master.models.Model")
    return model
