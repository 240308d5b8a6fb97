"""``python -m master.export.compat_run REQUEST.json``: one FMU, alone in an SSP package, stepped by libcosim or Ecos
for the compatibility matrix (:mod:`master.export.compat`), in a child process of its own (a master's crash or
refusal must not take the matrix down).

The request names the master, the unpacked package's folder (one component, ``fmu``, its bound parameter set
``fmu.ssv``), the steps, the step size, the identifiers to read after each step (``name``) and the .npz to
write. A failure is one line on stderr, exit status 1.
"""
from __future__ import annotations

import json
import sys

import numpy as np

from master.outputs.processes import error_line, exit_child

COMPONENT, SET = "fmu", "inputs"  # the component's name in the package; the name of its parameter set


def libcosim(request: dict) -> dict:
    """libcosim's fixed-step master on the package (it applies the bound parameter set itself)."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    from libcosimpy._internal import get_last_error_message  # its assertion hides libcosim's own reason

    log_output_level(CosimLogLevel.ERROR)
    try:
        execution = CosimExecution.from_ssp_file(request["ssp"])
    except AssertionError:
        raise RuntimeError(get_last_error_message()) from None
    index = {info.name.decode(): info.index for info in execution.slave_infos()}[COMPONENT]
    variables = {v.name.decode(): v.reference for v in execution.slave_variables(index)}
    missing = [n for n in request["read"] if n not in variables]
    if missing:
        raise RuntimeError(f"libcosim shows no variable {', '.join(missing)}")
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    rows = []
    for _ in range(request["steps"]):
        if not execution.step():
            raise RuntimeError(f"libcosim failed a step: {execution.status()}")
        rows.append(observer.last_real_values(index, [variables[n] for n in request["read"]]))
    return {name: np.array(column) for name, column in zip(request["read"], np.array(rows).T)}


def ecos(request: dict) -> dict:
    """Ecos's fixed-step master on the package, its bound parameter set applied by name."""
    from ecospy import EcosLib, EcosSimulation

    EcosLib.set_log_level("off")
    sim = EcosSimulation(ssp_path=request["ssp"], step_size=request["step_size"])
    if not sim.init(0.0, SET if request.get("bound") else None):
        raise RuntimeError(f"Ecos could not initialize: {EcosLib.get_last_error()}")
    rows = []
    for _ in range(request["steps"]):
        sim.step()
        rows.append([sim.get_real(f"{COMPONENT}::{name}") for name in request["read"]])
    sim.terminate()
    return {name: np.array(column) for name, column in zip(request["read"], np.array(rows).T)}


if __name__ == "__main__":
    try:
        with open(sys.argv[1], encoding="utf-8") as file:
            request = json.load(file)
        result = {"libcosim": libcosim, "ecos": ecos}[request["master"]](request)
        with open(request["out"], "wb") as file:
            np.savez(file, **result)
        status = 0
    except BaseException as error:  # noqa: BLE001: one line for the parent, whatever happened
        print(error_line(error), file=sys.stderr)
        status = 1
    exit_child(status)
