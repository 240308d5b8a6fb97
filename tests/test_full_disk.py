"""A full disk: exit status 1 naming the file that could not be written, nothing half-written left beside DIR, and
the same command resumes or replaces what a run cut short left.

The disk fills up by injection (a write raising ENOSPC as the kernel's does, ``OSError(28)`` naming no file), in
the process that writes: a command run as ``python -c`` with the patch before ``rhi.master.commands.cli.main``, or a
unit called here.
"""
from __future__ import annotations

import errno
import json
import os
import pathlib
import subprocess
import sys
from pathlib import Path

import pytest

from rhi.master.cosim import ConfigError
from tests.faults import ENV, snapshot, tiny_checkpoint
from tests.sweep_files import sweep_file

# A write deep in a library (zipfile's, inside pythonfmu's builder) fails as a full disk makes it fail.
ZIP_FULL = """
import errno, sys, zipfile
def full(self, *args, **kwargs):
    raise OSError(errno.ENOSPC, "No space left on device")
zipfile.ZipFile.write = full
from rhi.master.commands.cli import main
sys.exit(main(sys.argv[1:]))
"""
# The disk fills up as a sweep writes its sweep.json, its first file.
SWEEP_JSON_FULL = """
import errno, sys
import rhi.master.sweeps.folder as folder
def full(path, data):
    raise OSError(errno.ENOSPC, "No space left on device", str(path))
folder.atomic_write = full
from rhi.master.commands.cli import main
sys.exit(main(sys.argv[1:]))
"""


def run(work: Path, *args, python: str | None = None, timeout=120):
    """``rhi ARGS`` (``python``: ``python -c`` that code with ARGS) in ``work``, TMPDIR and RHI_CACHE beside it."""
    for name in ("tmp", "cache"):
        (work.parent / name).mkdir(exist_ok=True)
    env = {**ENV, "TMPDIR": str(work.parent / "tmp"), "RHI_CACHE": str(work.parent / "cache")}
    command = [sys.executable, *(["-c", python] if python else ["-m", "rhi"]), *map(str, args)]
    return subprocess.run(command, cwd=work, env=env, capture_output=True, text=True, timeout=timeout)


def last_line(done) -> str:
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    return lines[-1] if lines else ""


# -- export-agent: the FMU that could not be written is named ----------------------------------------------
def test_export_agent_onto_a_full_disk_names_the_fmu_exit_1_and_leaves_nothing(tmp_path):
    from rhi.components.body.kinematics import REST_POSE
    from rhi.master.decoders.training_data import HALF_RANGES

    work = tmp_path / "work"
    work.mkdir()
    tiny_checkpoint(work / "tiny.pt", rest_pose=list(REST_POSE), half_ranges=list(HALF_RANGES))
    (work / "c.toml").write_text("[experiment]\nresolution = 16\n[decoder]\nfast = false\n")
    before = snapshot(work)
    done = run(work, "export-agent", "--config", "c.toml", "--decoder", "conv", "--checkpoint", "tiny.pt",
               "--out", "A.fmu", python=ZIP_FULL)
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert last_line(done) == "rhi export-agent: error: A.fmu: No space left on device"
    assert snapshot(work) == before  # no A.fmu, no .A.fmu.XXXXXXXX.partial
    assert os.listdir(tmp_path / "tmp") == []


# -- reach, experiment, phenomena: the staging folder beside DIR -------------------------------------------
def test_a_full_disk_as_the_staging_folder_is_made_is_the_machine_s_and_leaves_nothing(tmp_path, monkeypatch):
    from rhi.master.outputs import files
    from rhi.master.outputs.files import STAGING_MARK, output_folder

    write_own = files.write_own

    def full(path, *args, **kwargs):  # mkdir takes an inode, the mark's first block finds no space
        if pathlib.Path(path).name == STAGING_MARK:
            raise OSError(errno.ENOSPC, "No space left on device")
        return write_own(path, *args, **kwargs)

    monkeypatch.setattr(files, "write_own", full)
    with pytest.raises(OSError) as failed:  # not ConfigError: exit status 1 (rhi.commands.cli), not 2
        with output_folder(tmp_path / "out", force=False):
            pytest.fail("the run must not start")
    assert not isinstance(failed.value, ConfigError)
    assert (failed.value.errno, failed.value.filename) == (errno.ENOSPC, str(tmp_path))
    assert os.listdir(tmp_path) == []  # no .out.XXXXXXXX.partial, no .out.lock


def test_a_read_only_parent_stays_a_refusal(tmp_path, monkeypatch):
    import tempfile

    from rhi.master.outputs.files import output_folder

    def denied(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(tempfile, "mkdtemp", denied)
    with pytest.raises(ConfigError, match=r"cannot write into .*: Permission denied"):
        with output_folder(tmp_path / "out", force=False):
            pytest.fail("the run must not start")


# -- sweep and fit: what a run cut short left is resumed ---------------------------------------------------
@pytest.mark.parametrize("existing", [False, True], ids=["new_dir", "existing_empty_dir"])
def test_a_sweep_cut_short_by_a_full_disk_is_taken_again_by_the_same_command(tmp_path, existing):
    import shutil

    from rhi.master.sweeps import plan as sweeps
    from rhi.master.sweeps.folder import sweep_folder

    work = tmp_path / "work"
    work.mkdir()
    sweep_file(work / "s.toml", trials=1, conditions=("left",), workers=1)
    if existing:
        (work / "out").mkdir()
    done = run(work, "sweep", "--config", "s.toml", "--out", "out", python=SWEEP_JSON_FULL)  # fails before any worker
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert last_line(done) == "rhi sweep: error: out/sweep.json: No space left on device"
    assert sorted(os.listdir(work)) == (["out", "s.toml"] if existing else ["s.toml"])  # a DIR it made: removed
    # The same command again, with and without --force: its folder's check, here (the rest is a sweep in an
    # empty DIR, tests/test_sweep.py), on two copies of what was left
    if existing:
        shutil.copytree(work / "out", work / "out_force", symlinks=True)
    sweep = sweeps.load(work / "s.toml")
    for out, force in ((work / "out", False), (work / "out_force", True)):
        with sweep_folder(out, sweep, force) as (records, _):
            assert records == {}
        assert json.loads((out / "sweep.json").read_text())["fingerprint"] == sweep.fingerprint


def test_a_fit_folder_holding_what_a_full_disk_left_is_taken_again(tmp_path):
    from rhi.master.fit.run import prepare_folder

    out = tmp_path / "out"
    (out / "figures").mkdir(parents=True)  # a fit cut short before fit.json: its one folder
    prepare_folder(out, "identity", "simulations")
    (out / "simulations" / "trials").mkdir(parents=True)  # its simulations cut short before their sweep.json
    (out / "simulations" / ".lock").touch()
    prepare_folder(out, "identity", "simulations")
    assert json.loads((out / "fit.json").read_text())["fingerprint"] == "identity"
    (out / "simulations" / "trials" / "mine.txt").write_text("a file of the user's")  # not a leftover: refused
    with pytest.raises(ConfigError, match="holds no sweep rhi fit wrote"):
        prepare_folder(out, "identity", "simulations")
