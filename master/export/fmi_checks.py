"""Static checks of an exported FMU, each a list of problems (empty: it passes): FMPy's ``validate_fmu``,
fmu-manipulation-toolbox's ``fmutool -check``, and the ``initial`` attribute each variable declares against the
table of the FMI standard (:func:`initial_problems`).

Example::

    from rhi.master.export.fmi_checks import CHECKS
    {name: check("Body.fmu") for name, check in CHECKS.items()}   # {"validate_fmu": [], ...}
"""
from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

# FMI 2.0 (section 2.2.7, the table of causality x variability) and FMI 3.0 (section 2.4.7.4): the initial values a
# variable may declare, the first its default; () where the attribute is not allowed. With exact or approx a start
# is required, with calculated it is not allowed.
INITIAL = {
    ("parameter", "fixed"): ("exact",), ("parameter", "tunable"): ("exact",),
    ("calculatedParameter", "fixed"): ("calculated", "approx"),
    ("calculatedParameter", "tunable"): ("calculated", "approx"),
    ("input", "discrete"): (), ("input", "continuous"): (),
    ("output", "constant"): ("exact",),
    ("output", "discrete"): ("calculated", "exact", "approx"),
    ("output", "continuous"): ("calculated", "exact", "approx"),
    ("local", "constant"): ("exact",),
    ("local", "fixed"): ("calculated", "approx"), ("local", "tunable"): ("calculated", "approx"),
    ("local", "discrete"): ("calculated", "exact", "approx"),
    ("local", "continuous"): ("calculated", "exact", "approx"),
    ("independent", "continuous"): (),
}


def variables(fmu) -> list[tuple[str, str, str, str | None, bool]]:
    """``(name, causality, variability, initial, has start)`` of every variable ``fmu``'s modelDescription.xml
    declares, FMI 2.0 or 3.0, the attributes as written (FMI's defaults where none is)."""
    with zipfile.ZipFile(fmu) as archive:
        root = ET.fromstring(archive.read("modelDescription.xml"))
    rows = []
    if root.get("fmiVersion", "").startswith("2."):
        for element in root.iterfind("ModelVariables/ScalarVariable"):
            typed = element[0]
            rows.append((element.get("name"), element.get("causality", "local"),
                         element.get("variability", "continuous"), element.get("initial"),
                         typed.get("start") is not None))
    else:
        for element in root.find("ModelVariables"):
            default = "continuous" if element.tag in ("Float32", "Float64") else "discrete"
            rows.append((element.get("name"), element.get("causality", "local"), element.get("variability", default),
                         element.get("initial"), element.get("start") is not None or element.find("Start") is not None))
    return rows


def initial_problems(fmu) -> list[str]:
    """Each variable of ``fmu`` whose ``initial`` (written, or FMI's default) the standard does not allow for its
    causality and variability, or whose start contradicts it; an output that leaves ``initial`` to the default
    is named too (the project's FMUs say it)."""
    problems = []
    for name, causality, variability, initial, has_start in variables(fmu):
        allowed = INITIAL.get((causality, variability))
        if allowed is None:
            problems.append(f"{name}: causality {causality} with variability {variability} is not allowed")
            continue
        if initial is not None and initial not in allowed:
            problems.append(f"{name}: initial={initial} is not allowed for a {variability} {causality} "
                            f"(allowed: {', '.join(allowed) or 'none'})")
            continue
        effective = initial or (allowed[0] if allowed else None)
        if causality == "output" and initial is None:
            problems.append(f"{name}: an output without initial (the default, {effective}, left unsaid)")
        if effective in ("exact", "approx") and not has_start:
            problems.append(f"{name}: initial={effective} needs a start")
        if effective == "calculated" and has_start:
            problems.append(f"{name}: initial=calculated with a start")
    return problems


def validate_problems(fmu) -> list[str]:
    """FMPy's ``validate_fmu``: the problems it finds in ``fmu``."""
    from fmpy.validation import validate_fmu

    return [" ".join(str(p).split()) for p in validate_fmu(str(fmu))]


def fmutool_problems(fmu, timeout: float = 120) -> list[str]:
    """``fmutool -input FMU -check`` (fmu-manipulation-toolbox): its ERROR and WARNING lines, or that it did not
    report the FMU compliant, or that it is not installed."""
    tool = shutil.which("fmutool") or str(Path(sys.executable).with_name("fmutool"))
    if not Path(tool).exists():
        return ["fmutool is not installed (the test extra: fmu-manipulation-toolbox)"]
    done = subprocess.run([tool, "-input", str(fmu), "-check"], capture_output=True, text=True, timeout=timeout)
    log = (done.stdout + done.stderr).splitlines()
    problems = [" ".join(line.split("|", 1)[-1].split()) for line in log if "ERROR" in line or "WARNING" in line]
    if done.returncode != 0 or not any("seems to be compliant" in line for line in log) or \
            not any("No semantic error" in line for line in log):
        problems.append(f"fmutool did not report it compliant (exit status {done.returncode})")
    return problems


CHECKS = {"validate_fmu": validate_problems, "fmutool -check": fmutool_problems, "initial": initial_problems}
