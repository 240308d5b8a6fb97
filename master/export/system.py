"""``rhi export-system`` and ``rhi run-system``: the experiment (or the reach) as an SSP 1.0 package of agent and
body FMUs.

:func:`export_system` builds the package (:mod:`rhi.master.export.ssp_package`); :func:`run_ssp` checks it
(:mod:`rhi.master.export.ssp_check`) and runs it, unchanged, under FMPy's SSP master (``fmpy.ssp``), libcosim
(``libcosimpy``) or Ecos (``ecospy``, :mod:`rhi.master.export.ssp_ecos`), in a child process (``python -m rhi.master.export.ssp_runner``): the masters load the FMUs'
native libraries, and a crash there must not take the command down.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from rhi.components.body import kinematics
from rhi.master.cosim import ConfigError, SimulationError
from rhi.master.export.ssp_check import Package, read_ssp, trial_parameters
from rhi.master.export.ssp_package import AGENT, BODY, MASTERS, MAX_STEPS, build_ssp
from rhi.master.export.ssp_runner import refusal
from rhi.master.outputs.files import atomic_write
from rhi.master.outputs.out_file import check_output_file, place_file
from rhi.master.outputs.scratch import scratch_folder


def run_ssp(path, master: str, trial: str | None = None, steps: int | None = None, timeout: float | None = None) -> dict:
    """Run an SSP package, unchanged, under an FMI master of someone else's, in a child process.

    Parameters
    ----------
    path : path
        The .ssp file (checked first: :func:`read_ssp`).
    master : str
        ``fmpy`` (FMPy's SSP master, ``fmpy.ssp.simulation.simulate_ssp``), ``libcosim``
        (``CosimExecution.from_ssp_file``) or ``ecos`` (``ecospy.EcosSimulation``).
    trial : str, optional
        A parameter file of ``resources/trials`` (``conv_left_sync_0``) for the agent, in place of the one
        the SSD binds; the same values are given to both masters as their API takes them.
    steps : int, optional
        Communication steps (default: the default experiment's stop time over its step size).
    timeout : float, optional
        Seconds for the child process.

    Returns
    -------
    dict
        ``"time"`` (steps,) s, the end of each step; ``"component.variable"`` (steps,) after each step,
        for every Real input and output of the components (FMPy: every connector of the SSD).

    Raises
    ------
    ConfigError
        A bad package, master, trial or step count, or a component that refused to start with the package's
        values (its own reason: a goal outside the ranges the decoders know, a variance of 0).
    SimulationError
        The master failed (its one-line reason).
    """
    import importlib.util

    if master not in MASTERS:
        raise ConfigError(f"--master {master!r} is not one of {', '.join(MASTERS)}")
    if master == "libcosim" and importlib.util.find_spec("libcosimpy") is None:
        raise ConfigError("--master libcosim needs libcosimpy (pip install libcosimpy==0.0.6, in the test extra)")
    if master == "ecos":
        from rhi.master.export.ssp_ecos import missing
        if (reason := missing()) is not None:
            raise ConfigError(reason)
    package = read_ssp(path)
    parameters = trial_parameters(package, trial)
    if package.step_size is None:
        raise ConfigError(f"{os.path.basename(package.path)}: its default experiment gives no step size")
    if steps is None:
        if package.stop_time is None:
            raise ConfigError(f"{os.path.basename(package.path)}: its default experiment gives no stop time")
        steps = round(package.stop_time / package.step_size)
    if steps < 1:
        raise ConfigError(f"steps must be at least 1, got {steps}")
    if steps > MAX_STEPS:
        raise ConfigError(f"{os.path.basename(package.path)}: {steps} steps, over the limit of {MAX_STEPS} "
                          "(lower the stop time, or give --steps)")
    with scratch_folder("rhi_ssp_run_") as folder:
        unpacked, fmus = unpack(package, Path(folder))
        request = Path(folder) / "request.json"
        request.write_text(json.dumps({
            "ssp": str(unpacked), "fmus": fmus, "master": master, "trial": trial, "steps": steps,
            "step_size": package.step_size,
            "parameters": {c: {k: [t, v] for k, (t, v) in values.items()} for c, values in parameters.items()},
            "connectors": {c: [v for v, (causality, kind) in package.variables[c].items()
                               if causality in ("input", "output") and kind == "Real"] for c in package.components},
            "inputs": {c: [v for v, (causality, kind) in package.variables[c].items()
                           if causality == "input" and kind == "Real"] for c in package.components},
            "out": str(Path(folder) / "result.npz")}))
        scratch = Path(folder) / "tmp"  # the masters' own unpacked copies, removed with the folder
        scratch.mkdir()
        env = {**os.environ, "TMPDIR": str(scratch),
               "PYTHONPATH": os.pathsep.join(filter(None, [str(Path(__file__).resolve().parents[2]),
                                                           os.environ.get("PYTHONPATH")]))}
        try:
            done = subprocess.run([sys.executable, "-m", "rhi.master.export.ssp_runner", str(request)], capture_output=True,
                                  text=True, timeout=timeout, env=env)
        except subprocess.TimeoutExpired:
            raise SimulationError(master, 0.0, f"did not finish within {timeout:g} s", "error") from None
        if done.returncode != 0 or not (Path(folder) / "result.npz").is_file():
            lines = [line for line in done.stderr.splitlines() if line.strip()]
            reason = lines[-1] if lines else f"the child process ended with status {done.returncode}"
            refused = refusal(folder, done.stderr)
            if refused:  # a component would not start with the package's values
                raise ConfigError(f"{os.path.basename(package.path)}: {refused} (refused as the FMU started under "
                                  f"{master})")
            raise SimulationError(master, 0.0, reason.removeprefix("rhi-ssp-runner: "), "error")
        with np.load(Path(folder) / "result.npz") as result:
            return {key: result[key] for key in result.files}


def unpack(package: Package, folder: Path) -> tuple[Path, dict]:
    """The checked package unpacked for a master: ``folder/ssp`` holds it (every member checked,
    :func:`rhi.components.archives.extract`), each component's FMU unpacked (checked) into ``folder/fmus/N``
    and, at its place in the package, packed again from those checked files (libcosim takes an FMU only
    as a zip archive, and unpacks it itself). Returns the package's folder and ``{source: FMU folder}``."""
    from rhi.components.archives import ArchiveError, extract, pack

    ssp, fmus = folder / "ssp", {}
    try:
        extract(package.path, ssp)
        for index, source in enumerate(package.components.values()):
            fmus[source] = str(extract(ssp / source, folder / "fmus" / str(index)))
            (ssp / source).unlink()
            pack(fmus[source], ssp / source)
    except ArchiveError as error:
        raise ConfigError(str(error)) from None
    return ssp, fmus


def final_drift_cm(values: dict, agent: str = AGENT, body: str = BODY) -> float:
    """The drift after the last step (cm): x of the forward kinematics of the agent's mu minus x of the body's
    sensed angles, as ``rhi.master.tasks.illusion.measures`` computes it."""
    perceived, _ = kinematics.forward(values[f"{agent}.mu_shoulder"][-1], values[f"{agent}.mu_elbow"][-1])
    real, _ = kinematics.forward(values[f"{body}.q_shoulder"][-1], values[f"{body}.q_elbow"][-1])
    return float(100.0 * (perceived - real))


def final_goal_distance_cm(values: dict, agent: str = AGENT, body: str = BODY) -> float:
    """The hand's distance to the goal's after the last step (cm), as ``rhi.master.tasks.reach.task.measures``
    computes it: the body's hand and the reach agent's goal hand."""
    return float(100.0 * np.hypot(values[f"{body}.hand_x"][-1] - values[f"{agent}.goal_hand_x"][-1],
                                  values[f"{body}.hand_y"][-1] - values[f"{agent}.goal_hand_y"][-1]))


def export_system(out, config: dict, kind: str | None = None, variant: str = "native", body: str | None = None,
                  trial: str | None = None, task: str = "illusion") -> Path:
    """``rhi export-system``: the agent FMU of ``task``, a body FMU (``variant`` exported, or the user's ``body``,
    checked against the body contract) and the SSP package around them, at ``out``; everything checked first.

    Parameters
    ----------
    out : path
        The .ssp to write.
    config : dict
        A loaded configuration of the task (protocol or reach plan, step size, steps, parameters, decoder).
    kind : str, optional
        The decoder (default: the configuration's first).
    variant : str
        The body exported with ``rhi export-body`` (native, kinematic, kinematic-c), when ``body`` is None.
    body : str, optional
        A body FMU of one's own.
    trial : str, optional
        ``CONDITION/STIMULATION/INDEX`` (the reach: ``BAND/INDEX``): the trial the SSD binds (default: the
        protocol's first, or the reach plan's).
    task : str
        ``illusion`` or ``reach`` (:func:`rhi.master.tasks.exportable`).

    Returns
    -------
    Path
        ``out``.
    """
    from rhi.components.body.contract import BODY_CONTRACT
    from rhi.components.fmu import check_contract
    from rhi.master.export.agent_fmu import export_agent
    from rhi.master.export.body import VARIANT_NAMES, export_body
    from rhi.master.tasks import exportable as task_named

    out = check_output_file(out, "SSP file", ".ssp")
    kind = kind or config["experiment"]["decoders"][0]
    bound = task_named(task).parse_trial(trial, config, kind) if trial else None
    if body is not None:
        problems = check_contract(body, BODY_CONTRACT)
        if problems:
            raise ConfigError(f"--body {body} cannot be used ({len(problems)} problem{'s' * (len(problems) > 1)}): "
                              + "; ".join(problems))
    elif variant not in VARIANT_NAMES:
        raise ConfigError(f"--body-variant {variant!r} is not one of {', '.join(VARIANT_NAMES)}")
    with scratch_folder("rhi_system_") as folder:
        agent, _ = export_agent(Path(folder) / "Agent.fmu", config, kind, task)
        body = body or str(export_body(Path(folder) / "Body.fmu", variant))
        return build_ssp(out, str(agent), body, config, kind, bound, task)


def write_csv(out, values: dict) -> Path:
    """The run's values as CSV (``time`` first, one row per step), written whole or not at all (the connectors'
    names, the package's free text, through rhi.master.outputs.tables.csv_text)."""
    from rhi.master.export.own_files import mark
    from rhi.master.outputs.tables import csv_text

    names = ["time"] + sorted(k for k in values if k != "time")
    rows = ([repr(float(v)) for v in row] for row in zip(*(values[name] for name in names)))
    data = csv_text(names, rows).encode("utf-8")

    def placed(temporary, path):  # marked as rhi's (its --force replaces only a table it marked), then put in place
        mark(temporary, data)
        place_file(temporary, path)  # never over a file that appeared at out meanwhile

    atomic_write(out, data, placed)
    return Path(out)
