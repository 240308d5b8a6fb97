"""The catalogue: bad inputs and faults run through the real command line.

Each case runs as ``rhi`` (cwd a fresh folder, RHI_CACHE a fresh folder) and asserts its exit status, one
line on stderr for a refusal (or the partial results of a run that failed in part), no "Traceback" anywhere,
and the file system unchanged outside the output (a snapshot of the case's folder before and after). A case
that needs a process of its own (a signal, a kill, a fault injected, a stdout that is not a pipe, an FMU
whose faults count the instances of a process) runs in a subprocess; the rest, refusals, call the command
line's main() in this process (tests/in_process.py), without seconds of start-up and imports each. No case
trains the default decoders: tiny checkpoints are trained once for the run.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import pytest

from tests.faults import CONV_ONLY, ENV, Resources, expand, experiment, snapshot
from tests.in_process import rhi_in_process


@pytest.fixture(scope="module")
def resources(fault_resources) -> Resources:
    return fault_resources  # made once per test run (tests/conftest.py)


TIMEOUT_1S = CONV_ONLY + "[fmu]\nstep_timeout_s = 1.0\n"
SWEEP_HEAD = ('[experiment]\ndecoders = ["conv"]\nconditions = ["left"]\nstimulations = ["sync"]\n'
              '[sweep]\ntrials = 1\nworkers = 1\ntask = "tests.sweep_tasks:fake_outcome"\n')
FULL_DISK_RUN = """
import errno, os, sys
os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core: the files are written here, where the patch is
import rhi.master.tasks.illusion.publish as publish
written = publish.atomic_write
def atomic_write(path, data):  # the disk fills up while the results are written
    if str(path).endswith("trials.csv"):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))
    return written(path, data)
publish.atomic_write = atomic_write
from rhi.master.commands.cli import main
sys.exit(main(sys.argv[1:]))
"""
FULL_DISK_EXPORT = """
import errno, sys, zipfile
write = zipfile.ZipFile.write
def full(self, *args, **kwargs):  # the disk fills up after a few files of the FMU
    if len(self.namelist()) > 3:
        raise OSError(errno.ENOSPC, "No space left on device", self.filename)
    return write(self, *args, **kwargs)
zipfile.ZipFile.write = full
from rhi.master.commands.cli import main
sys.exit(main(sys.argv[1:]))
"""


def old_fmu() -> bytes:
    """An FMU as rhi writes one, by what --force checks (rhi.master.export.own_files): the old file a full disk keeps."""
    import io
    import zipfile

    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("modelDescription.xml", '<fmiModelDescription fmiVersion="2.0" generationTool="rhi"/>')
    return buffer.getvalue()


OLD_FMU = old_fmu()


@dataclass
class Case:
    """One bad input or fault. ``args`` (after ``rhi``) may name the module's resources: {conv}, {vae},
    {fmu:NAME}. The case runs in a fresh folder ``work`` (inside a folder that is snapshot), with a fresh
    RHI_CACHE."""

    name: str
    args: list[str]
    status: int                 # 2 refused; 1 failed in part (partial results) or the machine's fault; 130, 143
    says: str                   # in stderr's last line (the only line for status 2)
    out: str | None = None      # the one path under work that may change (None: nothing may)
    files: dict = field(default_factory=dict)  # made in work first: name -> text, bytes or None (a folder)
    stdout: str = "pipe"        # "pipe", "closed" (a pipe nobody reads) or "full" (/dev/full)
    interrupt: int | None = None  # sent when the hanging FMU blocks
    python: str | None = None   # run ``python -c`` this (a fault injected) instead of ``python -m rhi``
    cache_is_file: bool = False
    check: Callable | None = None  # more: check(work, result)

    @property
    def own_process(self) -> bool:
        """Signals, a fault injected, a stdout that is not a pipe, and the faulty FMUs (they count instances made
        in a process, hang, or end it) need a process of their own."""
        return (self.interrupt is not None or self.python is not None or self.stdout != "pipe"
                or any(argument.startswith("{fmu:") and argument != "{fmu:unloadable}" for argument in self.args))


def toml(text):
    return {"conv_only.toml": CONV_ONLY, "c.toml": text}


def summary_rows(work, out="out"):
    import csv
    with open(work / out / "summary.csv") as file:
        return list(csv.DictReader(file))


def partial_results(work, result):
    rows = summary_rows(work)
    assert [(r["condition"], r["stimulation"], r["n_trials"]) for r in rows] == [
        ("left", "sync", "1"), ("left", "async", "1"), ("center", "sync", "0"), ("center", "async", "1"),
        ("right", "sync", "1"), ("right", "async", "1")]
    assert rows[2]["drift_cm_mean"] == "" and rows[0]["drift_cm_mean"] != ""
    run = json.loads((work / "out" / "run.json").read_text())
    assert [(t["condition"], t["stimulation"]) for t in run["failed_trials"]] == [("center", "sync")]
    assert (work / "out" / "figures" / "a_drift_final.png").is_file()
    assert "conv/center/sync trial 0" in result.stderr


def whole_results(work, result):
    assert len(summary_rows(work)) == 6 and (work / "out" / "run.json").is_file()


CASES = [
    # -- the output folder: never anything but our own output --------------------------------------
    Case("out_dot_force", experiment("--out", ".", "--force"), 2, "is the working folder",
         files={"conv_only.toml": CONV_ONLY, "thesis.tex": "precious"}),
    Case("out_empty_force", experiment("--out", "", "--force"), 2, "--out is empty",
         files={"conv_only.toml": CONV_ONLY, "thesis.tex": "precious"}),
    Case("out_dotdot_force", experiment("--out", "..", "--force"), 2, "is the working folder or a folder above it",
         files={"conv_only.toml": CONV_ONLY}),
    Case("out_cwd_by_another_name", experiment("--out", "../work", "--force"), 2, "is the working folder",
         files={"conv_only.toml": CONV_ONLY}),
    Case("out_foreign_force", experiment("--out", "results", "--force"), 2,
         "is not an earlier rhi experiment output (it holds notes.txt)",
         files={"conv_only.toml": CONV_ONLY, "results/notes.txt": "mine"}),
    Case("out_foreign_run_json_force", experiment("--out", "results", "--force"), 2,
         "is not an earlier rhi experiment output",
         files={"conv_only.toml": CONV_ONLY, "results/run.json": '{"command": "my tool"}'}),
    Case("out_not_empty", experiment("--out", "results"), 2, "exists and is not empty (use --force",
         files={"conv_only.toml": CONV_ONLY, "results/x.txt": "x"}),
    Case("out_is_a_file", experiment("--out", "results", "--force"), 2, "exists and is not a folder",
         files={"conv_only.toml": CONV_ONLY, "results": "a file"}),
    Case("out_under_proc", experiment("--out", "/proc/rhi-run"), 2, "cannot write into /proc",
         files={"conv_only.toml": CONV_ONLY}),
    Case("out_parent_missing", experiment("--out", "no/such/run"), 2, "does not exist",
         files={"conv_only.toml": CONV_ONLY}),
    # -- checkpoints: kind, folder, resolution, found before any training ---------------------
    Case("vae_as_conv_checkpoint", ["experiment", "--quick", "--config", "conv_only.toml", "--conv-checkpoint", "{vae}",
                                    "--out", "out"], 2, "a vae decoder, given as the conv decoder",
         files={"conv_only.toml": CONV_ONLY}),
    Case("checkpoint_is_a_folder", experiment("--out", "out", ckpt=False) + ["--conv-checkpoint", "ckpts"], 2,
         "ckpts is a folder, not a checkpoint file", files={"conv_only.toml": CONV_ONLY, "ckpts": None}),
    Case("checkpoint_missing", experiment("--out", "out", ckpt=False) + ["--conv-checkpoint", "none.pt"], 2,
         "none.pt does not exist", files={"conv_only.toml": CONV_ONLY}),
    Case("checkpoint_other_resolution", experiment("--resolution", "64", "--out", "out"), 2,
         "trained at resolution 32 px but the camera renders 64 px", files={"conv_only.toml": CONV_ONLY}),
    Case("bad_vae_found_before_conv_is_trained", ["experiment", "--quick", "--vae-checkpoint", "vae.pt", "--out", "out"],
         2, "vae.pt: not a decoder checkpoint", files={"vae.pt": "not a checkpoint"}),
    Case("cache_is_a_file", experiment("--out", "out", ckpt=False), 2, "(RHI_CACHE) is not a folder",
         files={"conv_only.toml": CONV_ONLY}, cache_is_file=True),
    # -- configuration ----------------------------------------------------------------------
    Case("config_not_utf8", experiment("--out", "out", config="c.toml"), 2, "is not UTF-8 text",
         files={"c.toml": b"\xff\xfe[experiment]\n"}),
    Case("config_is_a_folder", experiment("--out", "out", config="c.toml"), 2, "is a folder, not a TOML file",
         files={"c.toml": None}),
    Case("config_unknown_key", experiment("--out", "out", config="c.toml"), 2, "did you mean brain.gamma0?",
         files={"c.toml": "[brain]\ngama0 = 0.1\n"}),
    Case("resolution_100000", experiment("--resolution", "100000", "--out", "out"), 2,
         "experiment.resolution must be at most 1024 pixels, got 100000 (it would need about",
         files={"conv_only.toml": CONV_ONLY}),
    Case("steps_beyond_memory", experiment("--out", "out", steps="1000000000"), 2, "more than this machine's",
         files={"conv_only.toml": CONV_ONLY}),
    Case("duplicate_decoders", experiment("--out", "out", config="c.toml"), 2, "experiment.decoders lists conv more",
         files=toml('[experiment]\ndecoders = ["conv", "conv"]\n')),
    Case("duplicate_conditions", experiment("--out", "out", config="c.toml"), 2,
         "experiment.conditions lists left more", files=toml('[experiment]\nconditions = ["left", "left"]\n')),
    Case("empty_decoders", experiment("--out", "out", config="c.toml"), 2, "experiment.decoders is empty",
         files=toml("[experiment]\ndecoders = []\n")),
    Case("empty_conditions", experiment("--out", "out", config="c.toml"), 2, "experiment.conditions is empty",
         files=toml("[experiment]\nconditions = []\n")),
    Case("condition_not_a_number", experiment("--out", "out", config="c.toml"), 2,
         "config key conditions.far = 'very' must be a float",
         files=toml('[experiment]\nconditions = ["far"]\n[conditions]\nfar = "very"\n')),
    Case("visual_variance_nan", experiment("--out", "out", config="c.toml"), 2,
         "decoder.visual_variance = nan must be a finite number", files=toml("[decoder]\nvisual_variance = nan\n")),
    Case("scheme_unknown", experiment("--out", "out", config="c.toml"), 2, "experiment.scheme = 'jakobi' is not one of",
         files=toml('[experiment]\nscheme = "jakobi"\n')),
    Case("substeps_zero", experiment("--out", "out", config="c.toml"), 2, "body.substeps = 0 is outside its range",
         files=toml("[body]\nsubsteps = 0\n")),
    Case("period_zero", experiment("--out", "out", config="c.toml"), 2, "stimulus.period = 0.0 is outside its range",
         files=toml("[stimulus]\nperiod = 0.0\n")),
    Case("preset_unknown", experiment("--out", "out", config="c.toml", ckpt=False), 2,
         "train setting preset = 'huge' is unknown", files=toml('[train]\npreset = "huge"\n')),
    Case("resolution_misfits_preset", experiment("--resolution", "12", "--out", "out", ckpt=False), 2,
         "resolution = 12 does not fit", files={"conv_only.toml": CONV_ONLY}),
    Case("step_timeout_negative", experiment("--out", "out", config="c.toml"), 2, "fmu.step_timeout_s must be >= 0",
         files=toml("[fmu]\nstep_timeout_s = -1.0\n")),
    # -- bodies -------------------------------------------------------------------------------------
    Case("fmu_not_a_zip", experiment("--body", "Body.fmu", "--out", "out"), 2, "Body.fmu cannot be used",
         files={"conv_only.toml": CONV_ONLY, "Body.fmu": "not a zip"}),
    Case("fmu_binary_does_not_load", experiment("--body", "{fmu:unloadable}", "--out", "out"), 2,
         "does not load on this machine", files={"conv_only.toml": CONV_ONLY}),
    # -- usage errors in one line ------------------------------------------------------------------
    Case("usage_missing_out", ["experiment", "--quick"], 2, "the following arguments are required: --out"),
    Case("usage_not_a_number", ["experiment", "--trials", "many", "--out", "o"], 2, "invalid int value: 'many'"),
    Case("usage_unknown_command", ["fly"], 2, "invalid choice: 'fly'"),
    # -- rhi train ---------------------------------------------------------------------------------
    Case("train_unknown_table", ["train", "--decoder", "conv", "--config", "c.toml", "--out", "c.pt"], 2,
         "unknown config key trian (did you mean train?)", files={"c.toml": "[trian]\nepochs = 1\n"}),
    Case("train_config_not_utf8", ["train", "--decoder", "conv", "--config", "c.toml", "--out", "c.pt"], 2,
         "is not UTF-8 text", files={"c.toml": b"[train]\nepochs = \xe9\n"}),
    Case("train_out_is_a_folder", ["train", "--decoder", "conv", "--out", "ckpts"], 2, "ckpts is a folder",
         files={"ckpts": None}),
    Case("train_out_under_proc", ["train", "--decoder", "conv", "--out", "/proc/conv.pt"], 2, "cannot write into /proc"),
    # -- rhi export-body ------------------------------------------------------------------------------
    Case("export_under_proc", ["export-body", "--out", "/proc/v.fmu"], 2, "cannot write into /proc"),
    Case("export_under_a_file", ["export-body", "--out", "afile.txt/v.fmu"], 2, "is not a folder",
         files={"afile.txt": "x"}),
    Case("export_onto_a_folder", ["export-body", "--out", "existing.fmu"], 2, "existing.fmu is a folder",
         files={"existing.fmu": None}),
    Case("export_unknown_variant", ["export-body", "--variant", "springy", "--out", "v.fmu"], 2,
         "--variant 'springy' is not one of native, kinematic"),
    Case("export_not_fmu", ["export-body", "--out", "v.zip"], 2, "must be a file name ending in .fmu"),
    # -- rhi sweep ------------------------------------------------------------------------------
    Case("sweep_out_under_proc", ["sweep", "--config", "s.toml", "--out", "/proc/x"], 2, "cannot write /proc/x",
         files={"s.toml": SWEEP_HEAD}),
    Case("sweep_out_dot_force", ["sweep", "--config", "s.toml", "--out", ".", "--force"], 2, "is the working folder",
         files={"s.toml": SWEEP_HEAD, "thesis.tex": "precious"}),
    Case("sweep_foreign_force", ["sweep", "--config", "s.toml", "--out", "results", "--force"], 2,
         "holds no sweep", files={"s.toml": SWEEP_HEAD, "results/figures/mine.png": "mine"}),
    Case("sweep_scheme_of_a_point", ["sweep", "--config", "s.toml", "--out", "sw"], 2,
         "sweep point 1 (experiment.scheme=\"jakobi\")",
         files={"s.toml": SWEEP_HEAD + '[sweep.grid]\n"experiment.scheme" = ["gauss-seidel", "jakobi"]\n'}),
    Case("sweep_condition_not_a_number", ["sweep", "--config", "s.toml", "--out", "sw"], 2,
         "conditions.far = 'very' must be a float", files={"s.toml": '[conditions]\nfar = "very"\n' + SWEEP_HEAD}),
    Case("sweep_not_utf8", ["sweep", "--config", "s.toml", "--out", "sw"], 2, "is not UTF-8 text",
         files={"s.toml": b"\xff[sweep]\n"}),
    # -- rhi bench ---------------------------------------------------------------------------------------
    Case("bench_checkpoint_is_a_folder", ["bench", "--quick", "--checkpoint", "ckpts"], 2, "is a folder",
         files={"ckpts": None}),
    # -- faults in the body: the rest is written, exit 1 -------------------------------------------
    Case("fmu_nan_in_the_only_trial_of_a_cell", experiment("--body", "{fmu:NanThirdArmPlant}", "--out", "out"), 1,
         "trial failed and left out: conv/center/sync trial 0", out="out", files={"conv_only.toml": CONV_ONLY},
         check=partial_results),
    Case("fmu_step_over_its_time_limit", experiment("--body", "{fmu:HangingArmPlant}", "--out", "out", config="c.toml"),
         1, "did not return within its time limit of 1 s in trial 2 at t = 0.1 s", out="out",
         files={"c.toml": TIMEOUT_1S}, check=partial_results),
    Case("fmu_stuck_in_native_code", experiment("--body", "{fmu:DeafArmPlant}", "--out", "out", config="c.toml"), 1,
         "cannot be stopped (it runs native code that does not return); ending the process",
         files={"c.toml": TIMEOUT_1S}),
    # -- signals: status 130 / 143, nothing half-written -------------------------------------------
    Case("ctrl_c_in_an_fmu_step", experiment("--body", "{fmu:HangingArmPlant}", "--out", "out"), 130,
         "interrupted by Ctrl-C; nothing half-written is left", files={"conv_only.toml": CONV_ONLY},
         interrupt=signal.SIGINT),
    Case("sigterm_in_an_fmu_step", experiment("--body", "{fmu:HangingArmPlant}", "--out", "out"), 143,
         "interrupted by SIGTERM; nothing half-written is left", files={"conv_only.toml": CONV_ONLY},
         interrupt=signal.SIGTERM),
    # -- the machine's faults: a full disk, a closed or full stdout ---------------------------------
    Case("disk_full_while_writing_results", experiment("--out", "out"), 1, "trials.csv: No space left on device",
         files={"conv_only.toml": CONV_ONLY}, python=FULL_DISK_RUN),
    Case("disk_full_while_exporting", ["export-body", "--out", "Body.fmu", "--force"], 1, "No space left on device",
         files={"Body.fmu": OLD_FMU}, python=FULL_DISK_EXPORT),
    Case("stdout_closed", experiment("--out", "out"), 1, "cannot write to standard output", out="out",
         files={"conv_only.toml": CONV_ONLY}, stdout="closed", check=whole_results),
    Case("stdout_full", experiment("--out", "out"), 1, "cannot write to standard output", out="out",
         files={"conv_only.toml": CONV_ONLY}, stdout="full", check=whole_results),
]


@dataclass
class Result:
    status: int
    stdout: str
    stderr: str
    before: dict   # snapshot of the case's folder before the run
    after: dict    # and after
    cache: list    # what RHI_CACHE holds after the run
    work: Path     # the case's working folder
    seconds: float = 0.0


def run_case(case: Case, resources: Resources, root: Path) -> Result:
    folder, cache, marker = root / case.name, root / f"{case.name}.cache", root / f"{case.name}.hanging"
    work = folder / "work"
    work.mkdir(parents=True)
    for name, content in case.files.items():
        path = work / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if content is None:
            path.mkdir()
        elif isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content)
    if case.cache_is_file:
        cache.write_text("a file where the cache should be")
    before = snapshot(folder)
    if not case.own_process:
        began = time.monotonic()
        done = rhi_in_process([expand(argument, resources) for argument in case.args], cwd=work,
                              environment={"RHI_CACHE": str(cache), "RHI_TEST_HANG_MARKER": str(marker)})
        cached = sorted(p.name for p in cache.iterdir()) if cache.is_dir() else []
        return Result(done.status, done.stdout, done.stderr, before, snapshot(folder), cached, work,
                      time.monotonic() - began)
    env = {**ENV, "RHI_CACHE": str(cache), "RHI_TEST_HANG_MARKER": str(marker)}
    command = [sys.executable] + (["-c", case.python] if case.python else ["-m", "rhi"])
    command += [expand(argument, resources) for argument in case.args]
    reader, stdout = None, subprocess.PIPE
    if case.stdout == "closed":
        reader, writer = os.pipe()
        os.close(reader)
        stdout = writer
    elif case.stdout == "full":
        stdout = open("/dev/full", "w")
    began = time.monotonic()
    process = subprocess.Popen(command, cwd=work, env=env, stdout=stdout, stderr=subprocess.PIPE, text=True)
    if case.stdout == "closed":
        os.close(stdout)
    elif case.stdout == "full":
        stdout.close()
    if case.interrupt is not None:
        deadline = time.monotonic() + 180
        while not marker.exists() and process.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.3)
        process.send_signal(case.interrupt)
    try:
        out, err = process.communicate(timeout=300)
    except subprocess.TimeoutExpired:
        process.kill()
        out, err = process.communicate()
    cached = sorted(p.name for p in cache.iterdir()) if cache.is_dir() else []
    return Result(process.returncode, out or "", err or "", before, snapshot(folder), cached, work,
                  time.monotonic() - began)


@pytest.fixture(scope="module")
def catalogue(resources, tmp_path_factory) -> dict[str, Result]:
    """Every case of CASES: those that need a process of their own two at a time (one per core), while the rest
    run one after the other in this process (in its main thread, as rhi's signal handling expects)."""
    root = tmp_path_factory.mktemp("catalogue")
    with ThreadPoolExecutor(max_workers=2) as pool:
        futures = {case.name: pool.submit(run_case, case, resources, root) for case in CASES if case.own_process}
        here = {case.name: run_case(case, resources, root) for case in CASES if not case.own_process}
    return {case.name: here[case.name] if case.name in here else futures[case.name].result() for case in CASES}


def last_line(text: str) -> str:
    lines = [line for line in text.replace("\r", "\n").splitlines() if line.strip()]
    return lines[-1] if lines else ""


@pytest.mark.parametrize("case", CASES, ids=[case.name for case in CASES])
def test_catalogue(catalogue, case):
    result = catalogue[case.name]
    shown = f"status {result.status}, stderr: {result.stderr[-1500:]!r}"
    assert result.status == case.status, shown
    assert "Traceback" not in result.stderr + result.stdout, shown
    if case.status == 2:
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("rhi") and ": error: " in lines[0], shown
    assert case.says in last_line(result.stderr), shown
    work = "work/" + (case.out or "\0")
    changed = {path for path in set(result.before) | set(result.after)
               if result.before.get(path) != result.after.get(path)}
    outside = sorted(path for path in changed if path != work.rstrip("/") and not path.startswith(work + "/"))
    assert not outside, f"changed outside the output: {outside}"
    if case.status != 0:  # nothing trained: a run that fails stops before training or uses the tiny checkpoints
        assert not [name for name in result.cache if name.endswith((".pt", ".npz"))], result.cache
    if case.check is not None:
        case.check(result.work, result)


def test_catalogue_size():
    """How many bad inputs and faults the catalogue runs through the command line: at least 60."""
    assert len(CASES) + 3 >= 60  # and the three of tests/test_cli_runs.py
