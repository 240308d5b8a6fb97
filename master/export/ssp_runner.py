"""``python -m rhi.master.export.ssp_runner REQUEST.json``: one SSP package run by FMPy's, libcosim's or Ecos's master
(:mod:`rhi.master.export.ssp_ecos`).

:func:`rhi.master.export.system.run_ssp` starts this in a child process and writes the request: the
package, the master, the steps and step size, each component's parameters (as the package binds
them, or the trial asked for) and the connectors to record. The result, ``time`` and
``component.variable`` arrays of one row per step, goes to the request's ``out`` (.npz). A failure is
one line on stderr and exit status 1; a component that refuses to start (its initialization or its first
step fails) is named in the words it logged (:func:`refusal`). The process ends with ``os._exit``: the
masters' and pythonfmu's libraries are left to the operating system, not to exit-time destructors (pythonfmu 0.7's
can abort the process, see components/fmu/library.py).
"""
from __future__ import annotations

import json
import os
import re
import sys

import numpy as np

from rhi.master.outputs.processes import die_with_parent, error_line, exit_child

# libcosim's log line of a message an FMU logged with status error or fatal
LOGGED = re.compile(r"\[FMI status=(?:error|fatal), category=[^\]]*\] (.*)")
LOG, STEPPED = "libcosim.log", "stepped"  # beside the request's out: libcosim's log; a first step done
REFUSED = "rhi-ssp-runner: refused: "  # the runner's last line for a component that refused to start


class Refused(RuntimeError):
    """A component refused to start (its initialization or first step failed); the message is its own words."""


def first_reason(messages) -> str | None:
    """The first error a component logged, skipping pythonfmu's generic line that follows an exception."""
    reasons = [m.strip() for m in messages if m.strip() and not m.startswith("Fatal py exception")]
    return reasons[0] if reasons else None


def refusal(folder: str, stderr: str) -> str | None:
    """Why a component refused to start, in its own words, after the child failed (its stderr ``stderr``, its
    request's folder ``folder``), or None: FMPy's reason from the runner's last line, libcosim's from its log
    when no step was done; under Ecos, whose process ends (Ecos steps on past an FMU's failed initialization)
    before a first step, that a component failed, without its reason (Ecos keeps the FMUs' messages to
    itself)."""
    from rhi.master.export.ssp_ecos import ECOS_FAILED, ECOS_LOG

    lines = [line for line in stderr.splitlines() if line.strip()]
    if lines and lines[-1].startswith(REFUSED):
        return lines[-1].removeprefix(REFUSED)
    if os.path.isfile(os.path.join(folder, ECOS_LOG)) and not os.path.exists(os.path.join(folder, STEPPED)) and \
            not any(line.startswith("rhi-ssp-runner: ") for line in lines):  # Ecos's process ended as it started
        return ECOS_FAILED
    log = os.path.join(folder, LOG)
    if os.path.exists(os.path.join(folder, STEPPED)) or not os.path.isfile(log):
        return None
    with open(log, encoding="utf-8", errors="replace") as file:
        return first_reason(match.group(1) for match in map(LOGGED.search, file) if match)


def logging_slave(messages: list):
    """FMPy's ``FMU2Slave``, instantiated with logging on and a logger that keeps the error and fatal
    messages in ``messages`` (FMPy's own prints them, if at all, only with logging on)."""
    from ctypes import byref

    from fmpy import fmi2

    def log(component, instance, status, category, message):
        if status >= 3:  # fmi2Error, fmi2Fatal
            messages.append((message or b"").decode("utf-8", "replace"))

    callbacks = fmi2.fmi2CallbackFunctions()
    callbacks.logger = fmi2.fmi2CallbackLoggerTYPE(log)
    callbacks.allocateMemory = fmi2.defaultCallbacks.allocateMemory
    callbacks.freeMemory = fmi2.defaultCallbacks.freeMemory
    try:
        from fmpy.logging import addLoggerProxy  # formats the FMU's variadic arguments
        addLoggerProxy(byref(callbacks))
    except Exception:  # noqa: BLE001: without it the message is the format string, still the FMU's
        pass

    class FMU2LoggingSlave(fmi2.FMU2Slave):  # FMPy loads the functions by the class name's "FMU2"
        logging = callbacks  # kept alive as long as the class, for the FMUs' calls

        def instantiate(self, visible=False, callbacks=None, loggingOn=False):
            return super().instantiate(visible, FMU2LoggingSlave.logging, True)

        def doStep(self, *args, **kwargs):
            status = super().doStep(*args, **kwargs)
            messages.append(None)  # a step done: a later failure is no refusal to start
            return status

    return FMU2LoggingSlave


def fmpy_run(request: dict) -> dict:
    """FMPy's SSP master (``fmpy.ssp.simulation.simulate_ssp``), its algorithm unchanged.

    It is given the package and its FMUs unpacked and checked already (the request's ``ssp`` folder and
    ``fmus``), in place of its own unzipping, which neither bounds sizes nor refuses links.
    FMPy applies no parameter binding of the SSD itself: it takes a parameter set whose names are
    prefixed with the component's name, which is what it is given here, from the package's own files.
    Its loop adds the step size to the time until it reaches the stop time; a stop time half a step
    before the last step's end gives exactly ``steps`` steps.
    """
    import io
    import zipfile

    from fmpy.ssp import simulation
    from fmpy.ssp.simulation import simulate_ssp
    from fmpy.ssp.ssd import Parameter, ParameterSet, read_ssd

    folder, fmus = request["ssp"], request["fmus"]

    def read_unpacked(_, validate=True):  # FMPy reads the SSD and its parameter files from a zip archive
        buffer = io.BytesIO()
        with zipfile.ZipFile(buffer, "w") as archive:
            for root, _folders, files in os.walk(folder):
                for file in files:
                    relative = os.path.relpath(os.path.join(root, file), folder).replace(os.sep, "/")
                    if relative not in fmus:
                        archive.write(os.path.join(root, file), relative)
        return read_ssd(buffer, validate)

    def unpacked(filename, *args, **kwargs):
        return folder if filename == folder else fmus[os.path.relpath(filename, folder).replace(os.sep, "/")]

    simulation.read_ssd, simulation.extract = read_unpacked, unpacked
    messages = []
    simulation.FMU2Slave = logging_slave(messages)

    parameters = ParameterSet(name="rhi")
    for component, values in request["parameters"].items():
        for name, (kind, value) in values.items():
            parameter = Parameter(name=f"{component}.{name}")
            parameter.type, parameter.value = kind, value
            parameters.parameters.append(parameter)
    h, steps = request["step_size"], request["steps"]
    try:
        rows = simulate_ssp(folder, start_time=0.0, stop_time=(steps - 0.5) * h, step_size=h,
                            parameter_set=parameters)
    except Exception:
        reason = None if None in messages else first_reason(messages)
        if reason:
            raise Refused(reason) from None
        raise
    result = {"time": rows["time"] + h}
    for name in rows.dtype.names:
        if name != "time":
            result[name] = np.asarray(rows[name], dtype=float)
    return result


def libcosim_run(request: dict) -> dict:
    """libcosim's fixed-step master (``CosimExecution.from_ssp_file``), unchanged, on the unpacked and checked
    package (the request's ``ssp`` folder): it applies the parameter set the SSD binds to each component; a
    trial asked for in its place is set as initial values."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    # libcosim writes its log (the FMUs' messages among it) to standard output: into a file, which the parent
    # reads when the child fails (a component's failure can end it in C++'s std::terminate)
    log = os.path.join(os.path.dirname(request["out"]), LOG)
    sys.stdout.flush()
    with open(log, "wb") as file:
        os.dup2(file.fileno(), 1)
    log_output_level(CosimLogLevel.ERROR)
    execution = CosimExecution.from_ssp_file(request["ssp"])
    slaves = {info.name.decode(): info.index for info in execution.slave_infos()}
    references = {}
    for component, index in slaves.items():
        variables = {v.name.decode(): v for v in execution.slave_variables(index)}
        references[component] = {name: variables[name].reference for name in request["connectors"][component]}
        for name, (kind, value) in request["parameters"].get(component, {}).items():
            setter = {"Real": execution.real_initial_value, "Integer": execution.integer_initial_value,
                      "Boolean": execution.boolean_initial_value}[kind]
            setter(index, variables[name].reference, value)
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    rows = {f"{c}.{n}": [] for c, names in references.items() for n in names}
    times = []
    for step in range(request["steps"]):
        if not execution.step():
            raise RuntimeError(f"libcosim failed a step: {execution.status()}")
        if step == 0:  # libcosim initializes the FMUs in its first step; a failure after it is no refusal
            open(os.path.join(os.path.dirname(request["out"]), STEPPED), "wb").close()
        times.append(execution.status().current_time / 1e9)
        for component, names in references.items():
            values = observer.last_real_values(slaves[component], list(names.values()))
            for name, value in zip(names, values):
                rows[f"{component}.{name}"].append(value)
    return {"time": np.array(times), **{key: np.array(value) for key, value in rows.items()}}


def main(path: str) -> int:
    """Run the request of the JSON file ``path`` under its master (FMPy, libcosim or Ecos) and save the result to
    its ``out`` (.npz); returns the exit status, 0."""
    die_with_parent()
    with open(path, encoding="utf-8") as file:
        request = json.load(file)
    if request["master"] == "ecos":
        from rhi.master.export.ssp_ecos import ecos_run  # after die_with_parent: its imports take seconds

        result = ecos_run(request, os.path.join(os.path.dirname(request["out"]), STEPPED))
    else:
        result = (fmpy_run if request["master"] == "fmpy" else libcosim_run)(request)
    with open(request["out"], "wb") as file:
        np.savez(file, **result)
    return 0


if __name__ == "__main__":
    try:
        status = main(sys.argv[1])
    except Refused as error:
        print(f"{REFUSED}{' '.join(str(error).split())}", file=sys.stderr)
        status = 1
    except BaseException as error:  # noqa: BLE001: one line for the parent, whatever happened
        print(f"rhi-ssp-runner: {error_line(error)}", file=sys.stderr)
        status = 1
    exit_child(status)
