"""The compatibility matrix's checks beyond the masters' runs (:mod:`rhi.master.export.compat`): the one-component SSP
package each FMU is run in under libcosim and Ecos (:func:`package`), read against the SSP 1.0 schemas
(:func:`schema_problems`); an FMU instantiated, freed and instantiated again in one fresh process
(:func:`twice_problems`); and an FMU's trajectory held to a reference CSV (:func:`reference_problems`).

Sources: the SSP 1.0 standard's XML schemas as FMPy ships them (``fmpy/ssp/schema``:
SystemStructureDescription.xsd, SystemStructureParameterValues.xsd; SystemStructureDescription11.xsd is SSP
1.1's and is not used), read with lxml (an FMPy dependency); the FMI cross-check rules' CSV layout (a ``time``
column, then the outputs; an array as its values separated by spaces, as ``fmpy.util.read_csv`` reads it) and
``fmpy.util.validate_result``'s tolerance band.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np

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
# The package's XML files and the SSP 1.0 schema each is read against.
SCHEMAS = {"SystemStructure.ssd": "SystemStructureDescription.xsd",
           "resources/fmu.ssv": "SystemStructureParameterValues.xsd"}


def package(fmu, folder: Path, held: dict, stop: float, step: float) -> Path:
    """The unpacked one-component package of ``fmu`` in ``folder``/ssp: the FMU as component ``fmu``, the
    ``held`` values bound as its parameter set ``resources/fmu.ssv`` (none: no set), the default experiment
    to ``stop`` in steps of ``step`` (OSP's annotation, which libcosim reads). Returns the package's folder."""
    ssp = Path(folder) / "ssp"
    (ssp / "resources").mkdir(parents=True)
    with zipfile.ZipFile(fmu) as source, zipfile.ZipFile(ssp / "resources" / "fmu.fmu", "w") as copy:
        for item in source.infolist():
            copy.writestr(item, source.read(item.filename))
    bindings = ""
    if held:
        parameters = "".join(f'<ssv:Parameter name="{n}"><ssv:Real value="{v!r}"/></ssv:Parameter>'
                             for n, v in held.items())
        (ssp / "resources" / "fmu.ssv").write_text(SSV.format(parameters=parameters))
        bindings = ('<ssd:ParameterBindings><ssd:ParameterBinding type="application/x-ssp-parameter-set" '
                    'source="resources/fmu.ssv"/></ssd:ParameterBindings>')
    (ssp / "SystemStructure.ssd").write_text(SSD.format(bindings=bindings, stop=stop, step=step))
    return ssp


def schema_problems(ssp: Path) -> list[str]:
    """Each error lxml finds reading the package's SystemStructure.ssd and its parameter set (if any) against
    the SSP 1.0 schemas FMPy ships, as ``file line N: message``; the schemas missing is one problem."""
    import fmpy
    from lxml import etree

    folder = Path(fmpy.__file__).parent / "ssp" / "schema"
    problems = []
    for member, xsd in SCHEMAS.items():
        if not (Path(ssp) / member).is_file():
            continue
        if not (folder / xsd).is_file():
            return [f"FMPy {fmpy.__version__} ships no SSP 1.0 schema {xsd} (fmpy/ssp/schema)"]
        schema = etree.XMLSchema(etree.parse(str(folder / xsd)))
        try:
            document = etree.parse(str(Path(ssp) / member))
        except etree.XMLSyntaxError as error:
            problems.append(f"{member}: {error}")
            continue
        if not schema.validate(document):
            problems += [f"{member} line {e.line}: {e.message}" for e in schema.error_log]
    return problems


def twice_problems(fmu, held: dict, read: list[str], step: float, folder: Path, timeout: float = 300) -> list[str]:
    """``fmu`` under FMPy's FMU2Slave or FMU3Slave in one fresh child process (:func:`rhi.master.export.compat_run.twice`):
    instantiated, initialized with ``held`` set, stepped once by ``step``, terminated and freed, then the same
    again. Problems: an exit status other than 0, anything on stderr (no warning is allowed: none appears), an
    output of ``read`` whose value after the second instance's step is not the first's to the bit."""
    folder = Path(folder)
    (folder / "tmp").mkdir(parents=True)
    request = folder / "request.json"
    request.write_text(json.dumps({"master": "twice", "fmu": str(Path(fmu).resolve()), "held": held, "read": read,
                                   "step_size": step, "unzip": str(folder / "unzip"), "out": str(folder / "out.npz")}))
    try:
        done = run_child(request, folder / "tmp", timeout)
    except subprocess.TimeoutExpired:
        return [f"no exit within {timeout:g} s"]
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    if done.returncode != 0:
        return [f"exit status {done.returncode}" + (f": {lines[-1]}" if lines else "")]
    if lines:
        return [f"stderr: {lines[0]}" + (f" (and {len(lines) - 1} more lines)" if len(lines) > 1 else "")]
    with np.load(folder / "out.npz") as result:
        first, second = ({n: result[f"{n}.{k}"] for n in read} for k in (1, 2))
    differ = [n for n in read if first[n].dtype != second[n].dtype or first[n].tobytes() != second[n].tobytes()]
    return [f"the second instance's first step differs from the first's: {', '.join(differ)}"] if differ else []


def run_child(request: Path, scratch: Path, timeout: float) -> subprocess.CompletedProcess:
    """``python -m rhi.master.export.compat_run REQUEST`` with this checkout importable and ``scratch`` as TMPDIR."""
    root = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, "TMPDIR": str(scratch),
           "PYTHONPATH": os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")]))}
    return subprocess.run([sys.executable, "-m", "rhi.master.export.compat_run", str(request)], capture_output=True,
                          text=True, timeout=timeout, env=env)


def write_reference(path: Path, result: np.ndarray) -> None:
    """``result`` (FMPy's structured array, ``time`` first) as a CSV in the FMI cross-check layout, each value
    as Python's shortest repr (read back to the bit; ``nan``, ``-inf`` as written)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [",".join(f'"{name}"' for name in result.dtype.names)]
    for row in result:
        lines.append(",".join(" ".join(repr(float(v)) for v in np.ravel(row[name])) for name in result.dtype.names))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def signals(result: np.ndarray) -> dict:
    """``{name: (samples,) array}`` of every output of ``result`` (not ``time``), an array output element by
    element (``image[1]``, ``image[2]``, ...: validate_result compares scalar signals only)."""
    found = {}
    for name in result.dtype.names[1:]:
        values = np.asarray(result[name], dtype=float).reshape(len(result), -1)
        if result.dtype[name].shape:
            found.update({f"{name}[{i + 1}]": values[:, i] for i in range(values.shape[1])})
        else:
            found[name] = values[:, 0]
    return found


def reference_problems(result: np.ndarray, reference: np.ndarray) -> list[str]:
    """Where ``result`` leaves ``reference`` (both structured, ``time`` first, as ``fmpy.util.read_csv`` reads
    the CSV): a column one has and the other lacks; per scalar signal, its non-finite samples (NaN, -inf: the
    agent's event times before the first event) not the reference's exactly; its finite samples outside
    ``fmpy.util.validate_result``'s band (its defaults: the reference resampled at 1000 points, widened by a
    20-point running min/max and by 10 % of its range, or of its value if constant, 0.5 if constant 0; the
    first and last samples are not counted); a result that ends before the reference."""
    from fmpy.util import validate_result

    if result.dtype.names != reference.dtype.names:
        return [f"columns {', '.join(result.dtype.names[1:])}; the reference's "
                f"{', '.join(reference.dtype.names[1:])}"]
    t, t_ref = np.asarray(result["time"], dtype=float), np.asarray(reference["time"], dtype=float)
    if t[-1] < t_ref[-1]:
        return [f"ends at {float(t[-1])!r} s, the reference at {float(t_ref[-1])!r} s"]
    problems = []
    mine, theirs = signals(result), signals(reference)
    for name, y_ref in theirs.items():
        y = mine[name]
        finite, finite_ref = np.isfinite(y), np.isfinite(y_ref)
        if len(y) != len(y_ref) or not np.array_equal(finite, finite_ref) or \
                not np.array_equal(y[~finite], y_ref[~finite_ref], equal_nan=True):
            problems.append(f"{name}: not the reference's non-finite samples")
            continue
        if finite_ref.sum() < 2:  # nothing to band: the finite sample, if any, must be the reference's
            if not np.array_equal(y[finite], y_ref[finite_ref]):
                problems.append(f"{name}: {y[finite].tolist()}, the reference {y_ref[finite_ref].tolist()}")
            continue
        outside = validate_result(np.rec.fromarrays([t[finite], y[finite]], names=["time", "y"]),
                                  np.rec.fromarrays([t_ref[finite], y_ref[finite]], names=["time", "y"]))
        if outside > 0:
            problems.append(f"{name}: {outside:.0%} of its samples outside validate_result's band")
    return problems
