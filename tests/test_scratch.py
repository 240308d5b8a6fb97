"""Scratch folders in TMPDIR (master/outputs/scratch.py): a run killed by SIGKILL leaves its folder, and the next run
removes it; a folder it cannot show a run of its own left (no mark, a live process's, a link, a FIFO mark) stays.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from rhi.master.outputs.scratch import MARK, clean_stale, scratch_folder, started
from tests.faults import ENV
from tests.test_hostile_files import ONE_BODY, body_fmu, one_body_package, write_zip  # noqa: F401 (fixture)


def test_only_marked_folders_of_ended_runs_are_removed(tmp_path):
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # reaped: its id names no process now (or a later one, started at another time)
    folders = {name: tmp_path / f"rhi_ssp_run_{name}" for name in ("dead", "reused", "alive", "unmarked", "fifo")}
    for folder in folders.values():
        (folder / "big").mkdir(parents=True)
    (folders["dead"] / MARK).write_text(f"{gone.pid} 123\n")
    (folders["reused"] / MARK).write_text(f"{os.getpid()} 1\n")  # this id, another start: an earlier process's
    (folders["alive"] / MARK).write_text(f"{os.getpid()} {started(os.getpid())}\n")
    os.mkfifo(folders["fifo"] / MARK)  # never opened (it would wait for ever)
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / MARK).write_text(f"{gone.pid} 123\n")
    (tmp_path / "rhi_ssp_run_link").symlink_to(outside, target_is_directory=True)
    assert sorted(clean_stale("rhi_ssp_run_", tmp_path)) == ["rhi_ssp_run_dead", "rhi_ssp_run_reused"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "outside", "rhi_ssp_run_alive", "rhi_ssp_run_fifo", "rhi_ssp_run_link", "rhi_ssp_run_unmarked"]
    assert (outside / MARK).is_file()


def test_a_scratch_folder_is_marked_while_in_use_and_gone_after(tmp_path, monkeypatch):
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile
    monkeypatch.setattr(tempfile, "tempdir", None)  # TMPDIR read again
    with scratch_folder("rhi_x_") as folder:
        assert folder.parent == tmp_path and folder.name.startswith("rhi_x_")
        assert (folder / MARK).read_text() == f"{os.getpid()} {started(os.getpid())}\n"
        assert clean_stale("rhi_x_", tmp_path) == []  # this process's, in use
    assert list(tmp_path.iterdir()) == []


def test_run_system_killed_by_sigkill_leaves_a_folder_the_next_run_removes(body_fmu, tmp_path):  # noqa: F811
    work, tmp = tmp_path / "work", tmp_path / "tmp"
    for folder in (work, tmp):
        folder.mkdir()
    long_run = ONE_BODY.replace('stopTime="0.05"', 'stopTime="9000"')  # 900,000 steps: minutes
    write_zip(work / "L.ssp", [("SystemStructure.ssd", long_run), ("resources/body.fmu", body_fmu.read_bytes())])
    one_body_package(body_fmu, work / "S.ssp")  # 5 steps
    env = {**ENV, "TMPDIR": str(tmp)}
    killed = subprocess.Popen([sys.executable, "-m", "rhi", "run-system", "L.ssp", "--out", "l.csv"], cwd=work,
                              env=env, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 30
    while not list(tmp.glob("rhi_ssp_run_*/request.json")) and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.5)  # the child under way
    killed.send_signal(signal.SIGKILL)
    killed.wait()
    left = [p.name for p in tmp.iterdir()]
    assert len(left) == 1 and left[0].startswith("rhi_ssp_run_"), left
    time.sleep(0.5)  # the child ends with its parent (tests/test_hostile_files.py checks it)
    # the next run, even one refused after the package's check (which has a scratch folder of its own)
    done = subprocess.run([sys.executable, "-m", "rhi", "run-system", "S.ssp", "--trial", "none", "--out", "s.csv"],
                          cwd=work, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "has no trial 'none'" in done.stderr, done.stderr[-2000:]
    assert list(tmp.iterdir()) == []
