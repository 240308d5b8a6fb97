"""``rhi export-agent``: the agent of a task as one FMI 2.0 co-simulation FMU, built with pythonfmu.

The FMU holds the slave script ``master/export/agent_slave.py``, the decoder checkpoint and
``rhi_agent.json`` (the task, the decoder's kind, the configuration, the ports) in its resources. It runs
in a Python that has the rhi package installed (the slave imports it; see agent_slave.py). The tasks
(the registered tasks with export hooks, :func:`rhi.master.tasks.exportable`): ``illusion``, the experiment's agent (master/export/agent.py), and ``reach``, the free
arm reaching to a seen goal (master/export/reach_agent.py).

Example::

    build_agent_fmu("Agent.fmu", "conv", config.load(), checkpoint)   # or: rhi export-agent --out Agent.fmu
"""
from __future__ import annotations

import importlib.util
import json
import os
import shutil
import tempfile
from pathlib import Path

from rhi.master import models
from rhi.master.cosim import ConfigError
from rhi.master.export.fmu_files import build_with_pythonfmu, built_beside, check_target, staged_script

MANIFEST = "rhi_agent.json"
CHECKPOINT = "decoder.pt"
SLAVE = Path(__file__).with_name("agent_slave.py")
SLAVES = {"2.0": SLAVE, "3.0": Path(__file__).with_name("agent_slave3.py")}  # FMI version -> the slave script


def ports(agent) -> list[list[str]]:
    """The agent's ports as ``[name, causality, type, unit]``, in value-reference order."""
    return [[v.name, v.causality, v.type, v.unit] for v in agent.variables.values()]


def make_agent(checkpoint: str, kind: str, config: dict, task: str = "illusion", name: str = "agent"):
    """The agent component of ``task`` (:func:`rhi.master.tasks.exportable`): ``Agent`` or ``ReachAgent``, built as they are."""
    import importlib

    from rhi.master.tasks import exportable as task_named

    module, _, class_name = task_named(task).agent.partition(":")
    return getattr(importlib.import_module(module), class_name)(checkpoint, kind, config, name=name)


def agent_from_resources(resources: str):
    """The :class:`~rhi.master.export.agent.Agent` an agent FMU's resources describe, checked against them.

    Parameters
    ----------
    resources : str
        The FMU's resources folder (``rhi_agent.json`` and the checkpoint).

    Returns
    -------
    (Agent, str, str)
        The agent (named ``agent``), the model name and a one-line description.

    Raises
    ------
    RuntimeError
        This rhi's agent declares other ports than the FMU's (it was built by another version).
    """
    from rhi.master.tasks import TASKS, exportable

    with open(os.path.join(resources, MANIFEST), encoding="utf-8") as file:
        manifest = json.load(file)
    task = manifest.get("task", "illusion")  # an FMU of before the tasks: the illusion's
    if task not in TASKS or not TASKS[task].exportable:
        raise RuntimeError(f"this agent FMU was built by another version of rhi: its task {task!r} is not one of "
                           f"{', '.join(name for name in TASKS if TASKS[name].exportable)}; export the agent again "
                           "with this one")
    agent = make_agent(os.path.join(resources, CHECKPOINT), manifest["decoder"], manifest["config"], task)
    if ports(agent) != manifest["ports"]:
        mine = {tuple(p) for p in ports(agent)}
        theirs = {tuple(p) for p in manifest["ports"]}
        differ = sorted(p[0] for p in mine ^ theirs) or ["their order"]
        raise RuntimeError(f"this agent FMU was built by another version of rhi: the installed one declares other "
                           f"ports ({', '.join(differ)}); export the agent again with this one")
    description = agent.summary.format(kind=manifest["decoder"], resolution=manifest["config"]["experiment"]["resolution"])
    return agent, exportable(task).model_name, f"{description}; rhi {manifest['rhi']}"


def check_fmi(fmi: str, task: str) -> None:
    """ConfigError, in one line, unless the agent of ``task`` is built for FMI ``fmi``: 2.0 (pythonfmu) for every
    task, 3.0 (pythonfmu3, the camera's image an array output) for the illusion's, whose camera it exposes."""
    if fmi not in SLAVES:
        raise ConfigError(f"--fmi {fmi!r} is not one of {', '.join(SLAVES)}")
    if fmi == "3.0" and task != "illusion":
        raise ConfigError(f"--fmi 3.0 is built for --task illusion only (its camera image as an array); --task {task} "
                          "is FMI 2.0")
    if fmi == "3.0" and importlib.util.find_spec("pythonfmu3") is None:
        raise ConfigError("--fmi 3.0 needs pythonfmu3 (pip install pythonfmu3==0.3.4, in the test extra)")


def build_agent_fmu(out, kind: str, config: dict, checkpoint: str, task: str = "illusion", fmi: str = "2.0") -> Path:
    """Build the agent FMU at ``out`` (a path ending in .fmu), whole or not at all.

    Parameters
    ----------
    out : path
        The FMU to write.
    kind : str
        The decoder's kind, ``conv`` or ``vae``.
    config : dict
        A loaded configuration: the resolution, the blur and the decoder's mode it fixes; the start
        values of the agent's parameters.
    checkpoint : str
        The decoder's checkpoint, copied into the FMU's resources.
    task : str
        ``illusion`` or ``reach`` (:func:`rhi.master.tasks.exportable`).
    fmi : str
        ``2.0`` (pythonfmu) or ``3.0`` (pythonfmu3, :mod:`rhi.master.export.agent_fmi3`; the illusion's agent).

    Returns
    -------
    Path
        ``out``.
    """
    from importlib import metadata

    check_fmi(fmi, task)
    out = check_target(out)
    agent = make_agent(checkpoint, kind, config, task)  # refuses a checkpoint of another kind or camera first
    try:
        version = metadata.version("rhi")
    except metadata.PackageNotFoundError:
        version = "unknown"
    manifest = {"task": agent.task, "decoder": kind, "config": config, "ports": ports(agent), "rhi": version}
    with tempfile.TemporaryDirectory(prefix="rhi_agent_") as staging:
        staging = Path(staging)
        try:
            script = staged_script(SLAVES[fmi], staging, "rhi_agent_slave" if fmi == "2.0" else "rhi_agent_slave3")
            (staging / MANIFEST).write_text(json.dumps(manifest, indent=1), encoding="utf-8")
            shutil.copyfile(checkpoint, staging / CHECKPOINT)
        except OSError as error:  # a full TMPDIR: shutil's writes name no file
            raise OSError(error.errno, error.strerror, error.filename or str(staging)) from error
        files = [staging / MANIFEST, staging / CHECKPOINT]
        build = lambda target: build_with_pythonfmu(script, target, files, "the agent FMU", fmi)
        return built_beside(out, build)


def export_agent(out, config: dict, kind: str | None = None, task: str = "illusion",
                 fmi: str = "2.0") -> tuple[Path, str]:
    """``rhi export-agent``: check everything, train the decoder if it is the default and not cached yet
    (as ``rhi experiment`` does), and build the agent FMU at ``out``.

    Parameters
    ----------
    out : path
        The FMU to write (checked before any work).
    config : dict
        A loaded configuration (``reach.load`` for the reach); ``decoder.<kind>_checkpoint`` names a
        checkpoint, or the default is used.
    kind : str, optional
        ``conv`` or ``vae`` (default: the configuration's first decoder).
    task : str
        ``illusion`` or ``reach``.
    fmi : str
        ``2.0`` or ``3.0`` (:func:`check_fmi`).

    Returns
    -------
    (Path, str)
        The FMU and the checkpoint it carries.
    """
    from rhi.master.decoders.cache import check_decoders, ensure_checkpoints
    from rhi.master.config.sources import check_parameters
    from rhi.master.tasks import exportable as task_named

    kind = kind or config["experiment"]["decoders"][0]
    if kind not in ("conv", "vae"):
        raise ConfigError(f"--decoder {kind!r} is not one of conv, vae")
    task_named(task)  # a known one
    check_fmi(fmi, task)
    model = models.of(config)
    if model.sees_pose:
        raise ConfigError(f"--model {model.name}: its brain reads the seen arm's pose through a pose encoder, which "
                          "the agent FMU does not carry (it carries the decoder only); export a model that reads "
                          "the image through the decoder (paper, or a model of one's own like it)")
    out = check_target(out)
    if task == "reach":
        check_carried(config)
    config = {**config, "experiment": {**config["experiment"], "decoders": [kind]}}
    check_parameters(config)
    check_decoders(config)
    checkpoints, _ = ensure_checkpoints(config, progress=False)
    return build_agent_fmu(out, kind, config, checkpoints[kind], task, fmi), checkpoints[kind]


def check_carried(config: dict) -> None:
    """The reach agent FMU carries the decoder only: the goal's term must be the pixel attractor."""
    from rhi.master.tasks.reach import task as reach

    if reach.attractor(config) != "pixels":
        raise ConfigError(f"reach.attractor = {config['reach']['attractor']!r} reads the goal with a pose encoder, "
                          "which the agent FMU does not carry: use \"pixels\" for --task reach")
