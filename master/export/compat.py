"""The compatibility matrix: every FMU rhi exports (the bodies native, kinematic, kinematic-c; the illusion's agent;
FMI 2.0 and 3.0 where built) x every check (:data:`master.export.fmi_checks.CHECKS`) and every master (FMPy,
libcosim, Ecos), each cell ``pass``, ``fail`` or ``not supported``, with the reason of every cell that is not a
pass.

A master's cell: the FMU alone, its inputs held (a body's command at its start, 0; the agent's sensed arm at the
resting pose, bound as a parameter set), stepped :data:`STEPS` steps of :data:`STEP` s: FMPy's ``simulate_fmu``,
libcosim and Ecos on a one-component SSP package (:mod:`master.export.compat_run`, a child process each). It
passes when every step is done and no output is NaN (the agent's event times are -inf before the first event),
and, for an FMI 3.0 FMU, every output equals its FMI 2.0 twin's under FMPy to the last bit (an array element by
element). A master that cannot load the FMU, or shows an array as fewer values than it holds, is ``not
supported``, in its own words.

``python -m master.export.compat`` measures the whole matrix (a minute: it builds every FMU and starts every
master) into :data:`RESULTS`; docs/fmi.md's table is written from that file by ``python -m master.reference``,
and tests/test_compat.py measures a cheap part of it again.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from master.export.fmi_checks import CHECKS

RESULTS = Path(__file__).resolve().parents[2] / "docs" / "fmi" / "compat.json"
STEP, STEPS = 2.0 ** -6, 5  # a step binary holds: every master's communication points are exact
ROWS = (("body", "native", "2.0"), ("body", "kinematic", "2.0"), ("body", "kinematic-c", "2.0"),
        ("body", "kinematic-c", "3.0"), ("agent", "illusion", "2.0"), ("agent", "illusion", "3.0"))
MASTERS = ("FMPy", "libcosim", "Ecos")
COLUMNS = (*CHECKS, *MASTERS)
PASS, FAIL, UNSUPPORTED = "pass", "fail", "not supported"
SSD = """<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription version="1.0" name="compat" xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
 xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon" xmlns:osp="https://opensimulationplatform.com/SSP/OSPAnnotations">
<ssd:System name="compat"><ssd:Elements><ssd:Component name="fmu" type="application/x-fmu-sharedlibrary"
 source="resources/fmu.fmu">{bindings}</ssd:Component></ssd:Elements></ssd:System>
<ssd:DefaultExperiment startTime="0.0" stopTime="{stop!r}"><ssd:Annotations><ssc:Annotation type="com.opensimulationplatform">
<osp:Algorithm><osp:FixedStepAlgorithm baseStepSize="{step!r}"/></osp:Algorithm></ssc:Annotation></ssd:Annotations>
</ssd:DefaultExperiment></ssd:SystemStructureDescription>
"""
SSV = """<?xml version="1.0" encoding="UTF-8"?>
<ssv:ParameterSet version="1.0" name="inputs" xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues">
<ssv:Parameters>{parameters}</ssv:Parameters></ssv:ParameterSet>
"""


def row_name(row) -> str:
    """``body kinematic-c, FMI 3.0``."""
    kind, variant, fmi = row
    return f"{kind} {variant}, FMI {fmi}"


def build(folder, config: dict, rows=ROWS) -> dict:
    """The FMUs of ``rows`` built into ``folder``: ``{row: path}`` (``config``: the agent's configuration, its
    conv checkpoint named)."""
    from master.export.agent_fmu import build_agent_fmu
    from master.export.body import export_body

    folder, fmus = Path(folder), {}
    for row in rows:
        kind, variant, fmi = row
        out = folder / f"{kind}-{variant}-{fmi[0]}.fmu"
        fmus[row] = (export_body(out, variant, fmi) if kind == "body" else
                     build_agent_fmu(out, "conv", config, config["decoder"]["conv_checkpoint"], variant, fmi))
    return fmus


def held_inputs(fmu) -> dict:
    """The inputs the FMU is given, held: the agent's sensed arm at the resting pose (its inputs start at NaN); a
    body's command at its start (none given)."""
    from fmpy import read_model_description

    from components.body import kinematics

    rest = {"q_shoulder": kinematics.REST_POSE[0], "q_elbow": kinematics.REST_POSE[1],
            "hand_x": kinematics.REST_HAND[0], "hand_y": kinematics.REST_HAND[1]}
    names = {v.name for v in read_model_description(str(fmu), validate=False).modelVariables if v.causality == "input"}
    return {name: value for name, value in rest.items() if name in names}


def outputs(fmu) -> list[str]:
    """The FMU's outputs, by name, in declaration order."""
    return list(sizes(fmu))


def sizes(fmu) -> dict:
    """``{output: number of values}`` of the FMU's outputs (an FMI 3.0 array's: the product of its dimensions)."""
    from fmpy import read_model_description

    return {v.name: int(np.prod([int(d.start) for d in v.dimensions])) if v.dimensions else 1
            for v in read_model_description(str(fmu), validate=False).modelVariables if v.causality == "output"}


def fmpy_run(fmu) -> dict:
    """FMPy's ``simulate_fmu``: ``{output: (steps, ...) array}`` after each step."""
    from fmpy import simulate_fmu

    names = outputs(fmu)
    result = simulate_fmu(str(fmu), start_time=0.0, stop_time=STEPS * STEP, step_size=STEP, output_interval=STEP,
                          start_values=held_inputs(fmu), output=names)
    return {name: np.asarray(result[name], dtype=float)[1:] for name in names}


def child_run(master: str, fmu, folder: Path, timeout: float = 300) -> dict:
    """libcosim or Ecos on a one-component package of ``fmu`` (in ``folder``), in a child process: ``{output:
    (steps,) array}``, or RuntimeError with the master's one-line reason."""
    ssp = folder / "ssp"
    (ssp / "resources").mkdir(parents=True)
    with zipfile.ZipFile(fmu) as source, zipfile.ZipFile(ssp / "resources" / "fmu.fmu", "w") as copy:
        for item in source.infolist():
            copy.writestr(item, source.read(item.filename))
    held = held_inputs(fmu)
    bindings = ""
    if held:
        parameters = "".join(f'<ssv:Parameter name="{n}"><ssv:Real value="{v!r}"/></ssv:Parameter>'
                             for n, v in held.items())
        (ssp / "resources" / "fmu.ssv").write_text(SSV.format(parameters=parameters))
        bindings = ('<ssd:ParameterBindings><ssd:ParameterBinding type="application/x-ssp-parameter-set" '
                    'source="resources/fmu.ssv"/></ssd:ParameterBindings>')
    (ssp / "SystemStructure.ssd").write_text(SSD.format(bindings=bindings, stop=STEPS * STEP, step=STEP))
    request = folder / "request.json"
    request.write_text(json.dumps({"master": master, "ssp": str(ssp), "steps": STEPS, "step_size": STEP,
                                   "read": outputs(fmu), "bound": bool(held), "out": str(folder / "out.npz")}))
    scratch = folder / "tmp"
    scratch.mkdir()
    root = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, "TMPDIR": str(scratch),
           "PYTHONPATH": os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")]))}
    done = subprocess.run([sys.executable, "-m", "master.export.compat_run", str(request)], capture_output=True,
                          text=True, timeout=timeout, env=env)
    if done.returncode != 0 or not (folder / "out.npz").is_file():
        lines = [line for line in done.stderr.splitlines() if line.strip()]
        raise RuntimeError(lines[-1] if lines else f"the process ended with status {done.returncode}")
    with np.load(folder / "out.npz") as result:
        return {key: result[key] for key in result.files}


def twin_equal(values: dict, twin: dict) -> list[str]:
    """The outputs of an FMI 3.0 run ``values`` that differ from its FMI 2.0 twin's run ``twin`` in any bit: an
    array (the C body's ``q``: ``q_shoulder``, ``q_elbow``) element by element; an output the twin lacks (the
    agent's ``image``) is not compared."""
    from master.export.c_body import ARRAYS

    differ = []
    for name, value in values.items():
        elements = ARRAYS[name][1] if name in ARRAYS else (name,)
        if not set(elements) <= set(twin):
            continue
        expected = np.stack([twin[e] for e in elements], axis=-1) if name in ARRAYS else twin[name]
        if np.shape(value) != np.shape(expected) or not np.array_equal(value, expected):
            differ.append(name)
    return differ


def master_cell(master: str, row, fmu, twin: dict | None, folder: Path) -> tuple[str, str, dict | None]:
    """``(result, reason, values)`` of ``fmu`` under ``master`` (the values None when it did not run)."""
    try:
        values = fmpy_run(fmu) if master == "FMPy" else child_run(master.lower(), fmu, folder)
    except Exception as error:  # noqa: BLE001: the master's own words
        reason = " ".join(str(error).split())
        reason = re.sub(r"'[^']*/([^/']+)'", r"'\1'", reason)  # a path of this run: its file's name
        unsupported = "Unsupported FMI version" in reason or "not supported" in reason.lower()
        return (UNSUPPORTED if unsupported else FAIL), f"{master}: {reason}"[:300], None
    lengths = {len(np.atleast_1d(v)) for v in values.values()}
    if lengths != {STEPS}:
        return FAIL, f"{sorted(lengths)} rows for {STEPS} steps", values
    short = [f"{name} ({np.size(values[name]) // STEPS} value a step for its {size})"
             for name, size in sizes(fmu).items() if np.size(values[name]) != STEPS * size]
    if short:  # the master shows an array as fewer values than it holds
        return UNSUPPORTED, f"{master} reads an FMI 3.0 array as one value: {', '.join(short)}", values
    bad = [name for name, value in values.items() if np.any(np.isnan(value))]  # the event times are -inf before one
    if bad:
        return FAIL, f"NaN: {', '.join(bad)}", values
    if twin is not None:
        differ = twin_equal(values, twin)
        if differ:
            return FAIL, f"differs from its FMI 2.0 twin under FMPy: {', '.join(differ)}", values
    return PASS, "", values


def measure(fmus: dict, rows=ROWS, columns=COLUMNS) -> dict:
    """The matrix of ``fmus`` (``{row: path}``): ``{row name: {column: [result, reason]}}``."""
    matrix, runs = {}, {}
    with tempfile.TemporaryDirectory(prefix="rhi_compat_") as scratch:
        for number, row in enumerate(rows):
            cells = {}
            for column in columns:
                if column in CHECKS:
                    problems = CHECKS[column](fmus[row])
                    cells[column] = [PASS, ""] if not problems else [FAIL, "; ".join(problems)[:300]]
                    continue
                twin = None
                if row[2] == "3.0":
                    twin = runs.get((row[0], row[1], "2.0", "FMPy"))
                    if twin is None:
                        twin = fmpy_run(fmus[(row[0], row[1], "2.0")])
                folder = Path(scratch) / f"{number}-{column}"
                result, reason, values = master_cell(column, row, fmus[row], twin, folder)
                runs[(*row, column)] = values
                cells[column] = [result, reason]
            matrix[row_name(row)] = cells
    return matrix


def table(matrix: dict) -> str:
    """The matrix as docs/fmi.md's table: a row per FMU, a column per check and master; a cell that is not a pass
    says why in a note under the table."""
    header = ["FMU", *(f"`{c}`" if c in CHECKS else c for c in COLUMNS)]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    notes = []
    for name, cells in matrix.items():
        shown = []
        for column in COLUMNS:
            result, reason = cells[column]
            if result != PASS:
                notes.append(reason)
                shown.append(f"{result} ({len(notes)})")
            else:
                shown.append(result)
        lines.append("| " + " | ".join([name, *shown]) + " |")
    lines += [""] + [f"({number}) {' '.join(note.split()).replace('|', '/')}" + "  " * (number < len(notes))
                     for number, note in enumerate(notes, 1)]
    return "\n".join(lines).rstrip()


def stored_table() -> str:
    """docs/fmi.md's table, from :data:`RESULTS` (``python -m master.reference`` writes it)."""
    return table(json.loads(RESULTS.read_text(encoding="utf-8"))["matrix"])


def main(argv: list[str]) -> int:
    """``python -m master.export.compat``: build every FMU (the --quick conv decoder for the agent, trained if not
    cached), measure the matrix and write :data:`RESULTS`; then ``python -m master.reference`` updates the docs."""
    from master import config as configuration
    from master.decoders.cache import ensure_checkpoints
    from master.outputs.files import atomic_write

    config = configuration.load(quick=True)
    config["experiment"]["decoders"] = ["conv"]
    checkpoints, _ = ensure_checkpoints(config, progress=False)
    config["decoder"]["conv_checkpoint"] = checkpoints["conv"]
    with tempfile.TemporaryDirectory(prefix="rhi_compat_fmus_") as folder:
        matrix = measure(build(folder, config))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(RESULTS, json.dumps({"step": STEP, "steps": STEPS, "matrix": matrix}, indent=1) + "\n")
    print(table(matrix))
    return 0


if __name__ == "__main__":
    status = main(sys.argv[1:])
    sys.stdout.flush()
    os._exit(status)  # pythonfmu's libraries are left to the operating system (components/fmu/library.py)
