"""The compatibility matrix: every FMU rhi exports (the bodies native, kinematic, kinematic-c, FMI 2.0 and 3.0; the
illusion's and the reach's agents, FMI 2.0 and, the illusion's, 3.0) x every check
(:data:`rhi.master.export.fmi_checks.CHECKS`, the SSP schemas), every master (FMPy, libcosim, Ecos), an instantiation after a freed one and a reference trajectory,
each cell ``pass``, ``fail`` or ``not supported``, with the reason of every cell that is not a pass.

A master's cell: the FMU alone, its inputs held (a body's command at its start, 0; an agent's sensed arm at the
resting pose, bound as a parameter set; the reach agent's goal its start, the plan's first), stepped
:data:`STEPS` steps of :data:`STEP` s: FMPy's ``simulate_fmu``, libcosim and Ecos on a one-component SSP package
(:mod:`rhi.master.export.compat_run`, a child process each). It passes when every step is done and no output is NaN
(the agent's event times are -inf before the first event), and, for an FMI 3.0 FMU, every output equals its FMI
2.0 twin's under FMPy to the last bit (an array element by element). A master that cannot load the FMU, or shows
an array as fewer values than it holds, is ``not supported``, in its own words.

The other columns (:mod:`rhi.master.export.compat_checks`): ``SSP schema``, that package's SystemStructure.ssd and
parameter set read against the SSP 1.0 schemas; ``instantiate-free-instantiate``, two instances one after the
other in one fresh process, the second's first step the first's to the bit and the process's exit clean;
``reference trajectory``, FMPy's run of :data:`REFERENCE_STEPS` steps within ``fmpy.util.validate_result``'s
band of the shipped CSV in :data:`REFERENCES` (written by ``--write-references``).

``python -m rhi.master.export.compat [--write-references]`` measures the whole matrix (about 50 s on 2 cores: it
builds every FMU and starts every master) into :data:`RESULTS`; docs/fmi.md's table is written from that file
by ``python -m rhi.master.reference``, and tests/test_compat.py measures a cheap part of it again.
"""
from __future__ import annotations

import json
import os
import re
import sys
import tempfile
from pathlib import Path

import numpy as np

from rhi.master.export.compat_checks import package, reference_problems, run_child, schema_problems, twice_problems
from rhi.master.export.compat_checks import write_reference
from rhi.master.export.fmi_checks import CHECKS

RESULTS = Path(__file__).resolve().parents[2] / "docs" / "fmi" / "compat.json"
REFERENCES = RESULTS.parent / "reference"  # a CSV per row, named by :func:`reference_path`
STEP, STEPS = 2.0 ** -6, 5  # a step binary holds: every master's communication points are exact
REFERENCE_STEPS = 64  # 1 s: more samples than the masters' 5 steps for validate_result, which skips the ends
ROWS = (("body", "native", "2.0"), ("body", "native", "3.0"), ("body", "kinematic", "2.0"), ("body", "kinematic", "3.0"),
        ("body", "kinematic-c", "2.0"), ("body", "kinematic-c", "3.0"), ("agent", "illusion", "2.0"),
        ("agent", "illusion", "3.0"), ("agent", "reach", "2.0"))
MASTERS = ("FMPy", "libcosim", "Ecos")
SCHEMA, TWICE, REFERENCE = "SSP schema", "instantiate-free-instantiate", "reference trajectory"
COLUMNS = (*CHECKS, SCHEMA, *MASTERS, TWICE, REFERENCE)
PASS, FAIL, UNSUPPORTED = "pass", "fail", "not supported"


def row_name(row) -> str:
    """``body kinematic-c, FMI 3.0``."""
    kind, variant, fmi = row
    return f"{kind} {variant}, FMI {fmi}"


def reference_path(row) -> Path:
    """The row's reference CSV: ``docs/fmi/reference/body-kinematic-c-fmi3.csv``."""
    kind, variant, fmi = row
    return REFERENCES / f"{kind}-{variant}-fmi{fmi[0]}.csv"


def build(folder, config: dict, rows=ROWS) -> dict:
    """The FMUs of ``rows`` built into ``folder``: ``{row: path}`` (``config``: the illusion agent's --quick
    configuration, its conv checkpoint named; the reach agent's is ``rhi reach --quick``'s with that checkpoint,
    as ``rhi export-agent --task reach --quick`` loads it)."""
    from rhi.master.export.agent_fmu import build_agent_fmu
    from rhi.master.export.body import export_body
    from rhi.master.tasks.reach import task as reach

    folder, fmus = Path(folder), {}
    for row in rows:
        kind, variant, fmi = row
        out = folder / f"{kind}-{variant}-{fmi[0]}.fmu"
        if kind == "body":
            fmus[row] = export_body(out, variant, fmi)
            continue
        checkpoint = config["decoder"]["conv_checkpoint"]
        given = config if variant == "illusion" else reach.load(quick=True, overrides={
            "decoder.conv_checkpoint": checkpoint, "experiment.decoders": ["conv"]})
        fmus[row] = build_agent_fmu(out, "conv", given, checkpoint, variant, fmi)
    return fmus


def held_inputs(fmu) -> dict:
    """The inputs the FMU is given, held: the agent's sensed arm at the resting pose (its inputs start at NaN); a
    body's command at its start (none given)."""
    from fmpy import read_model_description

    from rhi.components.body import kinematics

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


def trajectory(fmu, steps: int = STEPS) -> np.ndarray:
    """FMPy's ``simulate_fmu`` of ``steps`` steps, the inputs held: its structured array, ``time`` then the
    outputs, a row at the start and one after each step."""
    from fmpy import simulate_fmu

    return simulate_fmu(str(fmu), start_time=0.0, stop_time=steps * STEP, step_size=STEP, output_interval=STEP,
                        start_values=held_inputs(fmu), output=outputs(fmu))


def fmpy_run(fmu) -> dict:
    """FMPy's ``simulate_fmu``: ``{output: (steps, ...) array}`` after each step."""
    result = trajectory(fmu)
    return {name: np.asarray(result[name], dtype=float)[1:] for name in outputs(fmu)}


def child_run(master: str, fmu, folder: Path, timeout: float = 300) -> dict:
    """libcosim or Ecos on a one-component package of ``fmu`` (in ``folder``), in a child process: ``{output:
    (steps,) array}``, or RuntimeError with the master's one-line reason."""
    held = held_inputs(fmu)
    ssp = package(fmu, folder, held, STEPS * STEP, STEP)
    request = folder / "request.json"
    request.write_text(json.dumps({"master": master, "ssp": str(ssp), "steps": STEPS, "step_size": STEP,
                                   "read": outputs(fmu), "bound": bool(held), "out": str(folder / "out.npz")}))
    scratch = folder / "tmp"
    scratch.mkdir()
    done = run_child(request, scratch, timeout)
    if done.returncode != 0 or not (folder / "out.npz").is_file():
        lines = [line for line in done.stderr.splitlines() if line.strip()]
        raise RuntimeError(lines[-1] if lines else f"the process ended with status {done.returncode}")
    with np.load(folder / "out.npz") as result:
        return {key: result[key] for key in result.files}


def twin_equal(values: dict, twin: dict) -> list[str]:
    """The outputs of an FMI 3.0 run ``values`` that differ from its FMI 2.0 twin's run ``twin`` in any bit: an
    array (a body's ``q``: ``q_shoulder``, ``q_elbow``) element by element; an output the twin lacks (the
    agent's ``image``) is not compared."""
    from rhi.components.body.contract import FMI3_ARRAYS as ARRAYS

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


def check_cell(column: str, row, fmu, folder: Path, write: bool = False) -> list[str]:
    """The problems of ``fmu`` (the FMU of ``row``) in a column that is not a master's, ``folder`` its own
    scratch; ``write``: the reference CSV is written from this run first."""
    from fmpy.util import read_csv

    if column in CHECKS:
        return CHECKS[column](fmu)
    if column == SCHEMA:
        return schema_problems(package(fmu, folder, held_inputs(fmu), STEPS * STEP, STEP))
    if column == TWICE:
        return twice_problems(fmu, held_inputs(fmu), outputs(fmu), STEP, folder)
    path, result = reference_path(row), trajectory(fmu, REFERENCE_STEPS)
    if write:
        write_reference(path, result)
    if not path.is_file():
        return [f"no reference {path.name} (python -m rhi.master.export.compat --write-references writes it)"]
    return reference_problems(result, read_csv(path))


def measure(fmus: dict, rows=ROWS, columns=COLUMNS, write: bool = False) -> dict:
    """The matrix of ``fmus`` (``{row: path}``): ``{row name: {column: [result, reason]}}`` (``write``: each
    row's reference CSV written from this run first)."""
    matrix, runs = {}, {}
    with tempfile.TemporaryDirectory(prefix="rhi_compat_") as scratch:
        for number, row in enumerate(rows):
            cells = {}
            for column in columns:
                folder = Path(scratch) / f"{number}-{column}"
                if column not in MASTERS:
                    problems = check_cell(column, row, fmus[row], folder, write)
                    cells[column] = [PASS, ""] if not problems else [FAIL, "; ".join(problems)[:300]]
                    continue
                twin = None
                if row[2] == "3.0":
                    twin = runs.get((row[0], row[1], "2.0", "FMPy"))
                    if twin is None:
                        twin = fmpy_run(fmus[(row[0], row[1], "2.0")])
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
    """docs/fmi.md's table, from :data:`RESULTS` (``python -m rhi.master.reference`` writes it)."""
    return table(json.loads(RESULTS.read_text(encoding="utf-8"))["matrix"])


def main(argv: list[str]) -> int:
    """``python -m rhi.master.export.compat [--write-references]``: build every FMU (the --quick conv decoder for the
    agents, trained if not cached), measure the matrix (``--write-references``: each row's reference CSV written
    from this run first) and write :data:`RESULTS`; then ``python -m rhi.master.reference`` updates the docs."""
    from rhi.master import config as configuration
    from rhi.master.decoders.cache import ensure_checkpoints
    from rhi.master.outputs.files import atomic_write

    unknown = [a for a in argv if a != "--write-references"]
    if unknown:
        print(f"python -m rhi.master.export.compat: unknown argument {unknown[0]!r} (only --write-references)",
              file=sys.stderr)
        return 2
    config = configuration.load(quick=True)
    config["experiment"]["decoders"] = ["conv"]
    checkpoints, _ = ensure_checkpoints(config, progress=False)
    config["decoder"]["conv_checkpoint"] = checkpoints["conv"]
    with tempfile.TemporaryDirectory(prefix="rhi_compat_fmus_") as folder:
        matrix = measure(build(folder, config), write="--write-references" in argv)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(RESULTS, json.dumps({"step": STEP, "steps": STEPS, "reference_steps": REFERENCE_STEPS,
                                      "matrix": matrix}, indent=1) + "\n")
    print(table(matrix))
    return 0


if __name__ == "__main__":
    status = main(sys.argv[1:])
    sys.stdout.flush()
    os._exit(status)  # pythonfmu's libraries are left to the operating system (components/fmu/library.py)
