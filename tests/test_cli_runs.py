"""Faults in several steps through the real command line: a second run while the first writes, a killed
run's staging cleaned by the next, --force replacing our output whole and nothing else."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.faults import CONV_ONLY, ENV, Resources, expand, experiment
from tests.in_process import rhi_in_process


@pytest.fixture(scope="module")
def resources(fault_resources) -> Resources:
    return fault_resources  # made once per test run (tests/conftest.py)


def start(resources, work, *args, marker=None):
    env = {**ENV, "RHI_CACHE": str(work.parent / "cache")}
    if marker is not None:
        env["RHI_TEST_HANG_MARKER"] = str(marker)
    return subprocess.Popen([sys.executable, "-m", "rhi", *[expand(a, resources) for a in args]], cwd=work,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def here(resources, work, *args):
    """A run that needs no process of its own (no signal, no hanging FMU; conv only: one batch, no worker pool):
    main() in this process (tests/in_process.py), as a subprocess would give it, without seconds of imports."""
    return rhi_in_process([expand(a, resources) for a in args], work, {"RHI_CACHE": str(work.parent / "cache")})


def wait_for(marker: Path, process) -> None:
    deadline = time.monotonic() + 180
    while not marker.exists():
        assert process.poll() is None and time.monotonic() < deadline, process.communicate()[1][-2000:]
        time.sleep(0.05)
    time.sleep(0.3)


def unlocked(path: Path, within_s: float = 60) -> None:
    """Wait until no process holds the flock on ``path`` (a killed process's children end a moment after it)."""
    import fcntl

    deadline = time.monotonic() + within_s
    with open(path, "rb") as file:
        while True:
            try:
                fcntl.flock(file, fcntl.LOCK_EX | fcntl.LOCK_NB)
                fcntl.flock(file, fcntl.LOCK_UN)
                return
            except BlockingIOError:
                assert time.monotonic() < deadline, f"{path} still locked {within_s} s after the kill"
                time.sleep(0.05)


def test_catalogue_a_second_run_is_refused_while_the_first_writes(resources, tmp_path):
    """Two runs into one DIR used to both print 'wrote' and the second replaced the first."""
    work, marker = tmp_path / "work", tmp_path / "hanging"
    work.mkdir()
    (work / "conv_only.toml").write_text(CONV_ONLY)
    first = start(resources, work, *experiment("--body", "{fmu:HangingArmPlant}", "--out", "race"), marker=marker)
    try:
        wait_for(marker, first)
        second = here(resources, work, *experiment("--out", "race"))
        err = second.stderr
        assert second.status == 2 and len(err.strip().splitlines()) == 1, err
        assert "another rhi run is writing race" in err and "Traceback" not in err
    finally:
        first.send_signal(signal.SIGINT)
        _, err = first.communicate(timeout=300)
    assert first.returncode == 130 and "Traceback" not in err, err
    assert sorted(os.listdir(work)) == ["conv_only.toml"]


def test_catalogue_a_killed_run_s_staging_is_cleaned_by_the_next(resources, tmp_path):
    """SIGKILL leaves the staging folder and the lock file; the next run into DIR removes ours, not others'."""
    work, marker = tmp_path / "work", tmp_path / "hanging"
    work.mkdir()
    (work / "conv_only.toml").write_text(CONV_ONLY)
    theirs = work / ".out.zzzzzzzz.partial"  # the same pattern, not ours: it stays
    theirs.mkdir()
    (theirs / "keep.txt").write_text("mine")
    killed = start(resources, work, *experiment("--body", "{fmu:HangingArmPlant}", "--out", "out"), marker=marker)
    wait_for(marker, killed)
    killed.kill()
    killed.communicate(timeout=60)
    unlocked(work / ".out.lock")  # the run's simulation process (rhi.master.runtime.contained) dies with it, a moment later
    left = sorted(os.listdir(work))
    assert ".out.lock" in left and len([n for n in left if n.endswith(".partial")]) == 2, left
    again = here(resources, work, *experiment("--out", "out"))
    assert again.status == 0 and "Traceback" not in again.stderr, again.stderr[-2000:]
    assert sorted(os.listdir(work)) == [".out.zzzzzzzz.partial", "conv_only.toml", "out"]
    assert (theirs / "keep.txt").read_text() == "mine"


def test_catalogue_force_replaces_our_output_whole_and_nothing_else(resources, tmp_path):
    work = tmp_path / "work"
    work.mkdir()
    (work / "conv_only.toml").write_text(CONV_ONLY)
    first = here(resources, work, *experiment("--out", "out"))
    assert first.status == 0, first.stderr[-2000:]
    old = (work / "out" / "summary.csv").read_bytes()
    second = here(resources, work, *experiment("--out", "out", "--force", "--trials", "2"))
    assert second.status == 0 and "Traceback" not in second.stderr, second.stderr[-2000:]
    assert (work / "out" / "summary.csv").read_bytes() != old
    assert sorted(os.listdir(work)) == ["conv_only.toml", "out"]  # no .old or .partial left
    (work / "out" / "notes.txt").write_text("mine")
    third = here(resources, work, *experiment("--out", "out", "--force"))
    err = third.stderr
    assert third.status == 2 and "it holds notes.txt" in err and len(err.strip().splitlines()) == 1, err
    assert (work / "out" / "notes.txt").read_text() == "mine"
