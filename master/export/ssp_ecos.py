"""Ecos (``ecospy``), the third FMI master of someone else's that runs an SSP package: its fixed-step algorithm,
unchanged, in the child process of :mod:`rhi.master.export.ssp_runner`.

Ecos reads the SSD and its parameter files itself and applies one named parameter set, the sets of that name
bound to any component, at initialization (``sim.init(parameter_set=NAME)``). The package binds the agent's
trial (its set named after the trial) and the body's ``body.ssv`` (named ``body``): Ecos applies the agent's
bound set itself; the values of the others (the body's, or the agent's of a trial asked for in place of the
bound one) are set before initialization, as libcosim's initial values. Ecos applies the named set over values set
before it, so with another trial asked for no set is named and every value is set.

:func:`missing` says, in one line, what this machine lacks to run it (the ``ecospy`` package; Debian's
``libtbb12``, which its library links to).
"""
from __future__ import annotations

import importlib.util
import os
import sys
from xml.etree import ElementTree as ET

import numpy as np

from rhi.master.export.ssp_package import AGENT, SSD, qualified

ECOS_LOG = "ecos.log"  # beside the request's out: Ecos's log
ECOS_FAILED = ("a component failed as it started; Ecos neither checks an FMU's status nor passes on its messages "
               "(--master libcosim or fmpy gives the component's reason)")
TBB = "libtbb.so.12"  # the Intel TBB runtime Ecos's Linux library links to


def missing() -> str | None:
    """What this machine lacks for ``--master ecos``, in one line, or None when it has everything."""
    if importlib.util.find_spec("ecospy") is None:
        return "--master ecos needs ecospy (pip install ecospy==0.7.2, in the test extra)"
    if sys.platform.startswith("linux"):
        import ctypes
        try:
            ctypes.CDLL(TBB)
        except OSError:
            return f"--master ecos needs {TBB}, which ecospy's library links to (Debian: apt-get install libtbb12)"
    return None


def bound_sets(folder: str) -> dict:
    """``{component: name}``: the name (the ``name`` attribute, which Ecos selects by) of the parameter set
    first bound to each component in the unpacked package ``folder``."""
    names = {}
    system = ET.parse(os.path.join(folder, SSD)).getroot().find(qualified("ssd:System"))
    for component in system.find(qualified("ssd:Elements")).findall(qualified("ssd:Component")):
        binding = component.find(f"{qualified('ssd:ParameterBindings')}/{qualified('ssd:ParameterBinding')}")
        if binding is not None and binding.get("source"):
            names[component.get("name")] = ET.parse(os.path.join(folder, binding.get("source"))).getroot().get("name")
    return names


def ecos_run(request: dict, stepped: str) -> dict:
    """Ecos's fixed-step master on the unpacked and checked package (the request's ``ssp`` folder).

    Parameters
    ----------
    request : dict
        The runner's request: ``ssp``, ``steps``, ``step_size``, ``parameters`` (``{component: {name: [type,
        value]}}``, what the run must apply), ``trial`` (None: the bound one), ``connectors`` (recorded: an
        output after each step, an input, ``inputs``, as the step was given it, as libcosim records them) and ``out``.
    stepped : str
        A file made once the first step is done (a failure after it is no refusal to start).

    Returns
    -------
    dict
        ``"time"`` and ``"component.variable"`` arrays, one row per step.

    Raises
    ------
    RuntimeError
        Ecos could not load the package, initialize or step it (Ecos's last error).
    """
    from ecospy import EcosLib, EcosSimulation

    log = os.path.join(os.path.dirname(request["out"]), ECOS_LOG)
    sys.stdout.flush()
    with open(log, "wb") as file:  # Ecos logs to standard output: into a file the parent reads on a failure
        os.dup2(file.fileno(), 1)
    EcosLib.set_log_level("warn")
    sets = bound_sets(request["ssp"])
    # the one set Ecos applies itself: the agent's bound one, unless a trial is asked in its place (Ecos's set,
    # applied after the values set here, would replace that trial's)
    applied = sets.get(AGENT) if request.get("trial") in (None, sets.get(AGENT)) else None
    own = {c for c, name in sets.items() if applied is not None and name == applied}
    try:
        sim = EcosSimulation(ssp_path=request["ssp"], step_size=request["step_size"])
    except Exception as error:  # noqa: BLE001: ecospy raises Exception with Ecos's last error
        raise RuntimeError(f"Ecos could not load the package: {error}") from None
    setters = {"Real": sim.set_real, "Integer": sim.set_integer, "Boolean": sim.set_bool}
    for component, values in request["parameters"].items():
        if component not in own:
            for name, (kind, value) in values.items():
                setters[kind](f"{component}::{name}", value)
    if not sim.init(0.0, applied):
        raise RuntimeError(f"Ecos could not initialize the system: {EcosLib.get_last_error()}")
    names = [f"{c}::{n}" for c, connectors in request["connectors"].items() for n in connectors]
    inputs = {f"{c}::{n}" for c, connectors in request.get("inputs", {}).items() for n in connectors}
    before = [(column, name) for column, name in enumerate(names) if name in inputs]
    after = [(column, name) for column, name in enumerate(names) if name not in inputs]
    rows = np.empty((request["steps"], len(names)))
    times = np.empty(request["steps"])
    for step in range(request["steps"]):
        for column, name in before:  # an input as the step gets it (as libcosim records it)
            rows[step, column] = sim.get_real(name)
        times[step] = sim.step()
        if step == 0:  # initialized and stepped: a failure after it is no refusal to start
            open(stepped, "wb").close()
        for column, name in after:  # an output after the step
            rows[step, column] = sim.get_real(name)
    sim.terminate()
    return {"time": times, **{name.replace("::", "."): rows[:, column] for column, name in enumerate(names)}}
