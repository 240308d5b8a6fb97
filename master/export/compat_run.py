"""``python -m rhi.master.export.compat_run REQUEST.json``: one FMU, alone in an SSP package, stepped by libcosim or Ecos
for the compatibility matrix (:mod:`rhi.master.export.compat`), in a child process of its own (a master's crash or
refusal must not take the matrix down); or (``twice``) instantiated, freed and instantiated again under FMPy.

The request names the master, the unpacked package's folder (one component, ``fmu``, its bound parameter set
``fmu.ssv``), the steps, the step size, the identifiers to read after each step (``name``) and the .npz to
write; ``twice`` names the FMU, the values to set before initialization and the folder to unzip it to. A failure
is one line on stderr, exit status 1.
"""
from __future__ import annotations

import json
import sys

import numpy as np

from rhi.master.outputs.processes import error_line, exit_child

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


def twice(request: dict) -> dict:
    """The FMU under FMPy's FMU2Slave or FMU3Slave (FMPy's own calls, as its ``simulate_fmu`` makes them):
    instantiated, the held values set, initialized, stepped once, terminated, freed (FMPy also unloads its
    library), then all again in this process: ``{name.1: value, name.2: value}`` after each instance's step."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    from fmpy.fmi3 import FMU3Slave

    description = read_model_description(request["fmu"], validate=False)
    unzip = extract(request["fmu"], request["unzip"])
    variables = {v.name: v for v in description.modelVariables}
    fmi2 = description.fmiVersion.startswith("2.")
    result = {}
    for instance in (1, 2):
        slave = (FMU2Slave if fmi2 else FMU3Slave)(
            guid=description.guid if fmi2 else description.instantiationToken, unzipDirectory=unzip,
            modelIdentifier=description.coSimulation.modelIdentifier, instanceName="fmu")
        slave.instantiate()
        if fmi2:
            slave.setupExperiment(startTime=0.0)
            for name, value in request["held"].items():
                slave.setReal([variables[name].valueReference], [value])
            slave.enterInitializationMode()
        else:
            for name, value in request["held"].items():
                slave.setFloat64([variables[name].valueReference], [value])
            slave.enterInitializationMode(startTime=0.0)
        slave.exitInitializationMode()
        slave.doStep(currentCommunicationPoint=0.0, communicationStepSize=request["step_size"])
        for name in request["read"]:
            variable = variables[name]
            if fmi2:
                value = slave.getReal([variable.valueReference])
            else:
                size = int(np.prod([int(d.start) for d in variable.dimensions])) if variable.dimensions else 1
                value = slave.getFloat64([variable.valueReference], nValues=size)
            result[f"{name}.{instance}"] = np.array(value, dtype=float)
        slave.terminate()
        slave.freeInstance()
    return result


if __name__ == "__main__":
    request = {}
    try:
        with open(sys.argv[1], encoding="utf-8") as file:
            request = json.load(file)
        result = {"libcosim": libcosim, "ecos": ecos, "twice": twice}[request["master"]](request)
        with open(request["out"], "wb") as file:
            np.savez(file, **result)
        status = 0
    except BaseException as error:  # noqa: BLE001: one line for the parent, whatever happened
        print(error_line(error), file=sys.stderr)
        status = 1
    if request.get("master") == "twice":
        sys.exit(status)  # what it checks includes the process's own exit: finalizers and atexit run
    exit_child(status)
