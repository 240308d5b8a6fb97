"""The everyday path as a user meets it: `rhi experiment` from an empty decoder cache, its wall time and CPU use.

Run as a child process (``python -m rhi experiment``) with ``RHI_CACHE`` an empty temporary folder, as
on a fresh clone: the decoders are the package's shipped ones when the settings are the defaults, else
trained. CPU utilisation is the child's CPU seconds (user + system, its own children included) over its
wall seconds: 200 % is both cores of a 2-core machine busy the whole run.
"""
from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def cpu_seconds_of_children() -> float:
    """User plus system CPU seconds of this process's children that have been waited for, so far."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def default_run(quick: bool = False, cache: str | None = None) -> dict:
    """Wall seconds, CPU seconds and utilisation of ``rhi experiment [--quick]`` from an empty cache.

    cache: a decoder cache to use instead of an empty one (tests: decoders trained already).

    Returns
    -------
    dict
        ``command``, ``wall_s``, ``cpu_s``, ``cpu_utilisation`` (CPU s / wall s), ``timings_s`` (the run's
        own, from its run.json) and ``fast_mode`` (which decoders ran fast).
    """
    root = Path(__file__).resolve().parents[2]
    with tempfile.TemporaryDirectory(prefix="rhi-bench-run-") as folder:
        command = [sys.executable, "-m", "rhi", "experiment", "--out", str(Path(folder) / "run")]
        command += ["--quick"] * quick
        environment = {**os.environ, "RHI_CACHE": cache or str(Path(folder) / "cache"),
                       "PYTHONPATH": str(root) + os.pathsep + os.environ.get("PYTHONPATH", "")}
        cpu_before, began = cpu_seconds_of_children(), time.perf_counter()
        child = subprocess.run(command, capture_output=True, text=True, env=environment)
        wall, cpu = time.perf_counter() - began, cpu_seconds_of_children() - cpu_before
        if child.returncode:
            raise RuntimeError(f"the default run failed: {child.stderr.strip().splitlines()[-1:]}")
        run = json.loads((Path(folder) / "run" / "run.json").read_text())
    return {"command": "rhi experiment" + " --quick" * quick + (f" (RHI_CACHE={cache})" if cache else " (empty RHI_CACHE)"),
            "wall_s": wall, "cpu_s": cpu,
            "cpu_utilisation": cpu / wall, "timings_s": run["timings_s"],
            "fast_mode": {kind: verdict["fast"] for kind, verdict in run["fast_mode"].items()}}
