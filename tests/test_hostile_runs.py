"""Hostile folders and files around a run: a phenomenon into a folder that is not its own, an --out FILE that
appears while a command runs, user's edits where a resumed run writes (docs/configuration.md, "What rhi refuses
and what it guarantees"; docs/safety.md)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.faults import refused, rhi, snapshot


def experiment_output(out: Path) -> None:
    """An `rhi experiment` output as rhi publishes one: its files, run.json and its manifest."""
    from rhi.master.outputs.files import output_folder

    with output_folder(out, False) as staging:
        (staging / "summary.csv").write_text("condition,drift_cm_mean\nleft,-1.0\n")
        (staging / "run.json").write_text(json.dumps({"command": "rhi experiment"}))


# -- a phenomenon writes only into a new folder or its own -------------------------------------------------
@pytest.mark.parametrize("force", [False, True])
@pytest.mark.parametrize("held", ["a user's file", "an experiment's output"])
def test_a_phenomenon_never_writes_into_a_folder_that_is_not_its_own(tmp_path, held, force):
    out = tmp_path / "work" / "out"
    if held == "a user's file":
        out.mkdir(parents=True)
        (out / "notes.txt").write_text("mine")
    else:
        out.parent.mkdir(parents=True)
        experiment_output(out)
    before = snapshot(tmp_path / "work")
    done = rhi(tmp_path, "phenomenon", "distance", "--out", "out", *(["--force"] if force else []))
    refused(done, "output folder out is not empty and holds no rhi phenomenon output")
    assert snapshot(tmp_path / "work") == before
    if held == "an experiment's output":  # still an experiment's: its --force takes it
        from rhi.master.outputs.files import foreign_entries

        assert foreign_entries(out) == []


# -- an --out FILE that appears while the command runs is left alone ----------------------------------------
def test_an_out_file_that_appears_while_run_system_or_an_export_runs_is_never_written_over(tmp_path):
    from argparse import Namespace

    import numpy as np

    from rhi.master.commands.export_agent import check_out
    from rhi.master.cosim import ConfigError
    from rhi.master.export.fmu_files import built_beside
    from rhi.master.export.system import write_csv
    from rhi.master.outputs.out_file import forget_checked

    forget_checked()
    csv, fmu = tmp_path / "run.csv", tmp_path / "Agent.fmu"
    check_out(Namespace(out=str(csv), force=False), "CSV file", ".csv")  # `rhi run-system --out run.csv`, before its run
    check_out(Namespace(out=str(fmu), force=False), "FMU file", ".fmu")  # `rhi export-agent --out Agent.fmu`
    csv.write_text("another program's table\n")  # ... which appear while the command runs
    fmu.write_bytes(b"another program's FMU")
    with pytest.raises(ConfigError, match="appeared or changed while this command ran"):
        write_csv(csv, {"time": np.array([0.0, 0.1]), "body.q": np.array([1.0, 2.0])})
    with pytest.raises(ConfigError, match="appeared or changed while this command ran"):
        built_beside(fmu, lambda target: Path(target).write_bytes(b"rhi's FMU") and target)
    assert csv.read_text() == "another program's table\n" and fmu.read_bytes() == b"another program's FMU"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["Agent.fmu", "run.csv"]  # no temporary file left
    # rhi's own table replaced with --force: it must be the same file still when the new one takes its place
    ours = tmp_path / "ours.csv"
    write_csv(ours, {"time": np.array([0.0])})
    check_out(Namespace(out=str(ours), force=True), "CSV file", ".csv")
    ours.write_text("time\n0.0\n0.5\n")  # edited meanwhile
    with pytest.raises(ConfigError, match="appeared or changed"):
        write_csv(ours, {"time": np.array([0.0])})
    assert ours.read_text() == "time\n0.0\n0.5\n"
    check_out(Namespace(out=str(tmp_path / "new.csv"), force=False), "CSV file", ".csv")  # nothing appears
    write_csv(tmp_path / "new.csv", {"time": np.array([0.0])})
    assert (tmp_path / "new.csv").read_text() == "time\n0.0\n"


# -- no participant id becomes a spreadsheet formula ---------------------------------------------------
HOSTILE_IDS = ["=cmd|' /C calc'!A0", "+HYPERLINK(\"http://x\")", "@SUM(A1:A9)", "-2+3", "\tTAB", "p1", "-1.5"]
# OWASP's "CSV Injection": a cell that starts with = + - @, a tab or a carriage return is prefixed with '; what reads
# as a number (-1.5) is a number, and stays one
NEUTRALISED = ["'=cmd|' /C calc'!A0", "'+HYPERLINK(\"http://x\")", "'@SUM(A1:A9)", "'-2+3", "'\tTAB", "p1", "-1.5"]


def test_participant_ids_are_written_so_no_spreadsheet_runs_them(tmp_path):
    import csv
    import io
    from types import SimpleNamespace

    import numpy as np

    from rhi.master.fit import report

    parameters = [SimpleNamespace(key="brain.gamma0")]
    samples = np.linspace(-1.0, 1.0, len(HOSTILE_IDS) * 4).reshape(len(HOSTILE_IDS), 4, 1)
    texts = {"posterior.csv": report.posterior_csv(parameters, HOSTILE_IDS, samples),
             "estimates.csv": report.estimates_csv(parameters, HOSTILE_IDS, samples),
             "predictive.csv": report.predictive_csv(["drift_cm[left/sync]"], HOSTILE_IDS, samples[:, 0, :],
                                                     samples)}
    for name, text in texts.items():
        rows = list(csv.reader(io.StringIO(text)))[1:]
        assert list(dict.fromkeys(row[0] for row in rows)) == NEUTRALISED, name
        numbers = [cell for row in rows for cell in row[2:]]
        assert all(cell.lstrip("-").replace(".", "", 1).replace("e-", "", 1).isdigit() for cell in numbers), name


# -- a resumed run writes over only what it can show it wrote ----------------------------------------------
def test_a_resumed_sweep_keeps_an_edited_summary_and_the_user_s_tmp_files(tmp_path):
    from rhi.master.cosim import ConfigError
    from rhi.master.sweeps import plan as sweeps
    from rhi.master.sweeps.folder import sweep_folder
    from tests.sweep_files import sweep_file

    sweep = sweeps.load(sweep_file(tmp_path / "s.toml", grid={"conditions.left": [-0.1, -0.2]}))
    out = tmp_path / "out"
    with sweep_folder(out, sweep, False) as (_, manifest):  # as rhi sweep writes its tables: each file, then listed
        (out / "summary.csv").write_text("rhi's summary\n")
        manifest.add("summary.csv")
        manifest.save()
    trial = sweep.trials[0].id
    ours, theirs = out / "trials" / f".{trial}.json.abcd1234.tmp", out / "trials" / ".notes.tmp"
    ours.write_text("half a record")  # what a kill leaves of atomic_write
    theirs.write_text("mine")
    with sweep_folder(out, sweep, False):  # resumed
        pass
    assert not ours.exists() and theirs.read_text() == "mine"
    (out / "summary.csv").write_text("my own notes on the results\n")  # edited between the runs
    with pytest.raises(ConfigError, match="summary.csv would be written over but is not what rhi sweep wrote"):
        with sweep_folder(out, sweep, False):
            pytest.fail("the resumed sweep must not start")
    assert (out / "summary.csv").read_text() == "my own notes on the results\n"


def test_a_resumed_fit_refuses_a_report_edited_since_rhi_wrote_it(tmp_path):
    from rhi.master.cosim import ConfigError
    from rhi.master.fit.run import reports_manifest, written

    out = tmp_path / "out"
    out.mkdir()
    (out / "posterior.csv").write_text("participant,sample\n")  # a fit of an older rhi, without a manifest: listed
    own = reports_manifest(out)
    (out / "estimates.csv").write_text("participant,parameter\n")
    written(own, "estimates.csv")
    reports_manifest(out)  # unchanged since: resumed
    (out / "posterior.csv").write_text("participant,sample\nedited,1\n")
    with pytest.raises(ConfigError, match="posterior.csv would be written over but is not what rhi fit wrote"):
        reports_manifest(out)
    assert (out / "posterior.csv").read_text() == "participant,sample\nedited,1\n"


# -- a delay no trial can show ---------------------------------------------------------------------------
@pytest.mark.parametrize("delay", ["1e300", "3600.0"])
def test_a_moving_hand_delay_longer_than_the_trial_is_refused(tmp_path, delay):
    from rhi.master.tasks.moving_hand import shipped_file

    text = shipped_file().read_text()
    (tmp_path / "work").mkdir()
    start = text.index("delays")
    line_end = text.index("\n", start)
    (tmp_path / "work" / "m.toml").write_text(text[:start] + f"delays = [0.0, {delay}]" + text[line_end:])
    done = rhi(tmp_path, "phenomenon", "moving-hand", "--config", "m.toml", "--out", "out")
    refused(done, "is longer than the trial")
    assert sorted(p.name for p in (tmp_path / "work").iterdir()) == ["m.toml"]


# -- a refusal is a refusal (2), the machine's fault the machine's (1), each before any work -------------
def test_a_phenomenon_into_a_folder_it_may_not_make_is_a_refusal(tmp_path, monkeypatch):
    import errno
    import os

    real = os.mkdir

    def denied(path, *args, **kwargs):  # a read-only parent (the tests may run as root, whom chmod does not stop)
        if Path(path).name == "out":
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real(path, *args, **kwargs)

    monkeypatch.setattr(os, "mkdir", denied)
    done = rhi(tmp_path, "phenomenon", "distance", "--out", "out")
    refused(done, "Permission denied")


def test_an_immutable_empty_dir_is_refused_before_any_work(tmp_path):
    import shutil
    import subprocess

    out = tmp_path / "work" / "out"
    out.mkdir(parents=True)
    if shutil.which("chattr") is None or subprocess.run(["chattr", "+i", str(out)], capture_output=True).returncode:
        pytest.skip("chattr +i is not available here (not root, or a file system without attributes)")
    try:
        done = rhi(tmp_path, "experiment", "--quick", "--out", "out")
        refused(done, "is immutable or append-only")
        assert not any((tmp_path / "cache").iterdir())  # refused before any decoder was trained
    finally:
        subprocess.run(["chattr", "-i", str(out)], check=True)


@pytest.mark.parametrize("compiler, status, says", [
    ("kill -XFSZ $$", 1, "was stopped by this machine (killed by signal 25)"),  # a file-size limit
    ("echo 'gcc: fatal error: Killed signal terminated program cc1' >&2; exit 1", 1, "stopped by this machine"),
    ("echo 'body.c:1:1: error: expected identifier' >&2; exit 1", 2, "failed: body.c:1:1: error"),  # the source's
])
def test_a_compiler_stopped_by_the_machine_is_the_machine_s_fault(tmp_path, monkeypatch, compiler, status, says):
    fake = tmp_path / "cc"
    fake.write_text(f"#!/bin/sh\n{compiler}\n")
    fake.chmod(0o755)
    monkeypatch.setenv("CC", str(fake))
    done = rhi(tmp_path, "export-body", "--variant", "kinematic-c", "--out", "Body.fmu")
    lines = done.stderr.strip().splitlines()
    assert done.returncode == status and len(lines) == 1 and says in lines[0], done.stderr[-2000:]
    assert "Traceback" not in done.stderr and not (tmp_path / "work" / "Body.fmu").exists()


def test_a_visual_variance_out_of_the_decoder_s_range_is_refused_with_the_configuration(tmp_path):
    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "c.toml").write_text("[decoder]\nvisual_variance = 1e-13\n")
    done = rhi(tmp_path, "experiment", "--quick", "--config", "c.toml", "--out", "out")
    refused(done, "decoder.visual_variance must be at least 1e-12")
    assert not any((tmp_path / "cache").iterdir())
    assert sorted(p.name for p in (tmp_path / "work").iterdir()) == ["c.toml"]


def test_run_system_force_replaces_only_a_table_rhi_marked_as_written(tmp_path):
    """A CSV of the user's that merely has run-system's shape is not rhi's; the one run-system wrote is, until
    edited (its mark, the sha256 of its bytes, no longer matches)."""
    import os

    import numpy as np

    from rhi.master.export.own_files import csv_problem
    from rhi.master.export.system import write_csv

    try:
        (tmp_path / "probe").write_text("x")
        os.setxattr(tmp_path / "probe", "user.rhi.sha256", b"x")
    except OSError:
        pytest.skip("this file system keeps no user extended attributes")
    ours, theirs = tmp_path / "ours.csv", tmp_path / "theirs.csv"
    write_csv(ours, {"time": np.array([0.0, 0.1]), "body.q_elbow": np.array([1.0, 2.0])})
    theirs.write_bytes(ours.read_bytes())  # the same shape and bytes, written by someone else
    assert csv_problem(ours) is None
    assert "does not carry rhi's mark" in (csv_problem(theirs) or "rhi's")
    with open(ours, "a") as file:
        file.write("0.2,3.0\n")  # edited since: not rhi's any more
    assert "does not carry rhi's mark" in (csv_problem(ours) or "rhi's")
