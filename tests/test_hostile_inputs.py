"""Hostile inputs: settings out of their bounds, names too long, checkpoints that are not there, verdicts and
listeners that are not what they claim, and processes that would outlive their command.

A refusal is asserted through the command line where it is the command's (one line on stderr, exit status 2,
no traceback, nothing written: tests.faults.rhi, in this process or a subprocess where noted, and refused), or a
function where it is the unit. No case trains a decoder.
"""
from __future__ import annotations

import json
import os
import re
import socketserver

import pytest

from rhi.master.cosim import ConfigError
from tests.faults import ENV, REPO, refused, rhi, snapshot


def load(overrides: dict, model: str = "paper"):
    from rhi.master import config

    return config.load(overrides=overrides, model_name=model)


# ======================================================================================================
# Every component parameter within its range and the component's rules when the configuration loads
# ======================================================================================================
@pytest.mark.parametrize("key, value, model, says", [
    ("brain.sync_sd", 0.0, "paper", "brain.sync_sd must be positive and finite, got 0.0"),
    ("brain.async_density", 0.0, "paper", "brain.async_density must be positive and finite"),
    ("brain.action_limit", 0.0, "paper", "brain.action_limit must be positive and finite"),
    ("stimulus.period", 0.0, "paper", "stimulus.period = 0.0 is outside its range [0.001, None] s"),
    ("stimulus.ball_distance", -1.0, "paper", "stimulus.ball_distance = -1.0 is outside its range"),
    ("conditions.left", -2.0, "paper", "conditions.left = -2.0 m (rubber_arm.offset_y = 0.0 m) puts the rubber hand "
                                       "out of the arm's reach"),
    ("brain.sync_sd", 0.0, "causal", "brain.sync_sd = 0.0 is outside its range [1e-12, None] s"),
    ("causal.pixel_weight", -1.0, "causal", "causal.pixel_weight: brain.pixel_weight = -1.0 is outside its range"),
])
def test_a_parameter_a_component_would_refuse_is_refused_when_the_configuration_loads(key, value, model, says):
    from rhi.master.cosim import ConfigError

    with pytest.raises(ConfigError, match=re.escape(says)):
        load({key: value}, model)


def test_sync_sd_zero_is_refused_by_the_command_before_any_training(tmp_path):
    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "c.toml").write_text('[experiment]\ndecoders = ["conv"]\n[brain]\nsync_sd = 0.0\n')
    before = snapshot(tmp_path)
    done = rhi(tmp_path, "experiment", "--quick", "--config", "c.toml", "--out", "out")
    refused(done, "brain.sync_sd must be positive and finite, got 0.0")
    assert snapshot(tmp_path) == {**before, **{name: ("folder",) for name in ("tmp", "cache")}}  # nothing trained


def test_a_checkpoint_named_for_a_decoder_that_does_not_run_must_exist(tmp_path):
    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "c.toml").write_text('[experiment]\ndecoders = ["conv"]\n')
    done = rhi(tmp_path, "experiment", "--quick", "--config", "c.toml", "--vae-checkpoint", "/nonexistent.pt",
               "--out", "out")
    refused(done, "decoder.vae_checkpoint: /nonexistent.pt does not exist")
    assert sorted(os.listdir(tmp_path / "work")) == ["c.toml"]


# ======================================================================================================
# Bounds on names and settings, each stated in docs/safety.md
# ======================================================================================================
@pytest.mark.parametrize("command", [["experiment", "--quick"], ["train", "--decoder", "conv"], ["sweep", "--config",
                                                                                                   "s.toml"]])
def test_an_output_name_over_the_file_system_s_limit_is_refused_naming_it(tmp_path, command):
    from rhi.master.outputs.out_file import NAME_MARGIN
    from tests.sweep_files import sweep_file

    (tmp_path / "work").mkdir()
    sweep_file(tmp_path / "work" / "s.toml", grid={"conditions.left": [-0.1]})
    limit = os.pathconf(tmp_path / "work", "PC_NAME_MAX")
    name = "a" * 300 + (".pt" if command[0] == "train" else "")
    done = rhi(tmp_path, *command, "--out", name)
    refused(done, f"has {len(name)} bytes, over the limit of {limit - NAME_MARGIN} (this file system's NAME_MAX of "
                  f"{limit}")
    assert sorted(os.listdir(tmp_path / "work")) == ["s.toml"]


@pytest.mark.parametrize("overrides, says", [
    ({"train.threads": 100000}, "train.threads = 100000 must be 0 (every usable core) to 1024"),
    ({"experiment.step_size": 1e300}, "experiment.step_size = 1e+300 s is over the limit of stimulus.period = 2 s"),
    ({"experiment.step_size": 0.2}, "must be below 2 x brain.action_time_constant = 0.2 s"),
    ({"experiment.step_size": 1.0, "brain.action_time_constant": float("inf"), "brain.proprioceptive_variance": 0.5},
     "must be below 2 x brain.proprioceptive_variance = 1 s"),
])
def test_threads_and_the_step_size_are_bounded(overrides, says):
    from rhi.master.cosim import ConfigError

    with pytest.raises(ConfigError, match=re.escape(says)):
        load(overrides)
    # just inside each bound: accepted (0.19 s < 2 x 0.1 s; 1024 threads)
    load({"experiment.step_size": 0.19, "train.threads": 1024})


def test_a_huge_step_size_is_one_line_without_numpy_s_warnings(tmp_path):
    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "c.toml").write_text("[experiment]\nstep_size = 1e300\n")
    refused(rhi(tmp_path, "experiment", "--quick", "--config", "c.toml", "--out", "out"), "is over the limit of "
            "stimulus.period")


def test_a_phenomenon_point_out_of_reach_is_refused_before_the_sweep_runs(tmp_path):
    (tmp_path / "work").mkdir()
    shipped = (REPO / "master" / "phenomena" / "distance.toml").read_text()
    (tmp_path / "work" / "far.toml").write_text(shipped.replace("0.55, 0.60]", "0.55, 0.95]"))
    done = rhi(tmp_path, "phenomenon", "distance", "--config", "far.toml", "--out", "out")
    refused(done, "sweep point 11 (conditions.right=0.95): conditions.right = 0.95 m (rubber_arm.offset_y = 0.0 m) puts "
                  "the rubber hand out of the arm's reach")
    assert sorted(os.listdir(tmp_path / "work")) == ["far.toml"]


# ======================================================================================================
# A fast-check verdict is trusted only when it is one
# ======================================================================================================
GOOD_VERDICT = {"fast": True, "reason": "checked", "relative_error": 0.001, "bound": 0.01, "trials": ["left sync 0"],
                "drift_exact_cm": [-4.8], "drift_fast_cm": [-4.8048]}
DAMAGED = {"not_json": "{not json", "not_an_object": "[1, 2]", "truncated": '{"fast": true, "reason": "che',
           "missing_field": json.dumps({k: v for k, v in GOOD_VERDICT.items() if k != "bound"}),
           "wrong_type": json.dumps({**GOOD_VERDICT, "fast": "yes"}),
           "wrong_item_type": json.dumps({**GOOD_VERDICT, "drift_fast_cm": ["x"]}),
           "inconsistent": json.dumps({**GOOD_VERDICT, "relative_error": 0.5})}


@pytest.fixture
def verdict_setup(tmp_path, monkeypatch):
    """A quick configuration, a stand-in checkpoint (the key hashes its bytes), an empty shipped folder, and
    the check replaced by one that counts its calls and answers GOOD_VERDICT (no trial runs)."""
    from rhi.master.tasks.illusion import fast_check

    (tmp_path / "cache").mkdir()
    (tmp_path / "shipped").mkdir()
    monkeypatch.setenv("RHI_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(fast_check, "SHIPPED", tmp_path / "shipped")
    calls = []
    monkeypatch.setattr(fast_check, "run_jobs", lambda function, jobs, workers=None: calls.extend(jobs) or
                        [dict(GOOD_VERDICT) for _ in jobs])
    (tmp_path / "conv.pt").write_bytes(b"stand-in checkpoint bytes")
    config = load({"experiment.decoders": ["conv"]})
    name = f"fast-check-conv-{fast_check.verdict_key(str(tmp_path / 'conv.pt'), config)}.json"
    return config, {"conv": str(tmp_path / "conv.pt")}, tmp_path / "cache" / name, tmp_path / "shipped" / name, calls


@pytest.mark.parametrize("damage", list(DAMAGED))
def test_a_damaged_cached_verdict_is_checked_again_and_rewritten_with_one_note(verdict_setup, capsys, damage):
    from rhi.master.runtime.logs import configured
    from rhi.master.tasks.illusion import fast_check

    config, checkpoints, cached, _, calls = verdict_setup
    cached.write_text(DAMAGED[damage])
    with configured(0):  # the note logged on stderr, as the command line sets it up
        assert fast_check.verdicts(config, checkpoints)["conv"] == GOOD_VERDICT
    assert len(calls) == 1 and json.loads(cached.read_text()) == GOOD_VERDICT  # checked again, rewritten whole
    said = capsys.readouterr().err.strip().splitlines()
    assert len(said) == 1 and said[0].startswith(f"rhi: note: the fast-check verdict {cached} is damaged (")
    assert said[0].endswith("); checking again")
    assert not [p for p in cached.parent.iterdir() if p.name.endswith(".tmp")]
    fast_check.verdicts(config, checkpoints)  # now sound: used as stored, no check, no note
    assert len(calls) == 1 and capsys.readouterr().err == ""


def test_a_damaged_shipped_verdict_is_a_clear_error_and_a_sound_one_is_used(verdict_setup):
    from rhi.master.cosim import ConfigError
    from rhi.master.tasks.illusion import fast_check

    config, checkpoints, cached, shipped, calls = verdict_setup
    shipped.write_text(DAMAGED["not_an_object"])
    with pytest.raises(ConfigError, match=re.escape(f"the shipped fast-check verdict {shipped} is damaged (not a "
                                                    "JSON object); reinstall rhi")):
        fast_check.verdicts(config, checkpoints)
    shipped.write_text(json.dumps(GOOD_VERDICT))
    assert fast_check.verdicts(config, checkpoints)["conv"] == GOOD_VERDICT and not calls and not cached.exists()


def test_every_shipped_verdict_is_sound():
    from rhi.master.tasks.illusion import fast_check

    shipped = sorted(fast_check.SHIPPED.glob("fast-check-*.json"))
    assert shipped and all(fast_check.verdict_problem(path.read_text()) is None for path in shipped)


# ======================================================================================================
# A listener that is not a Dask scheduler: refused within the limit, in one line
# ======================================================================================================
class AnswersAtOnce(socketserver.BaseRequestHandler):
    """Speaks first, as a Dask scheduler does, but HTTP (dask would read its first 8 bytes as a length)."""

    def handle(self):
        self.request.sendall(b"HTTP/1.0 200 OK\r\nContent-Type: text/html\r\n\r\n<html>hello</html>\r\n")


class AnswersWhenSpokenTo(socketserver.BaseRequestHandler):
    """Silent until it gets a byte, then HTTP, whatever was said (dask, speaking, would read a 3 EiB length)."""

    def handle(self):
        if self.request.recv(1):
            self.request.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")


@pytest.mark.parametrize("server", ["http.server", "answers_at_once", "answers_when_spoken_to"])
def test_an_http_listener_as_scheduler_is_refused_within_the_limit(tmp_path, server):
    import http.server
    import threading
    import time

    from rhi.master.sweeps.runner import CONNECT_TIMEOUT_S
    from tests.sweep_files import sweep_file

    handler = {"http.server": http.server.SimpleHTTPRequestHandler, "answers_at_once": AnswersAtOnce,
               "answers_when_spoken_to": AnswersWhenSpokenTo}[server]
    listener = socketserver.ThreadingTCPServer(("127.0.0.1", 0), handler)
    listener.daemon_threads = True
    threading.Thread(target=listener.serve_forever, daemon=True).start()
    (tmp_path / "work").mkdir()
    sweep_file(tmp_path / "work" / "s.toml", grid={"conditions.left": [-0.1]})
    began = time.monotonic()
    try:
        # own process: its timeout is the check, and dask's threads stay out of the test's process
        done = rhi(tmp_path, "sweep", "--config", "s.toml", "--scheduler",
                   f"tcp://127.0.0.1:{listener.server_address[1]}", "--out", "out", timeout=60, own_process=True)
    finally:
        listener.shutdown()
        listener.server_close()
    took = time.monotonic() - began
    refused(done, "cannot reach the Dask scheduler at tcp://127.0.0.1:")
    assert "it answers HTTP" in done.stderr  # http.server waits to be spoken to: the probe speaks when it is silent
    assert "MemoryError" not in done.stderr  # dask reads its answer's "HTTP/1.0" as a length: 3.07 EiB
    assert took < CONNECT_TIMEOUT_S + 10  # the limit, plus the command's start-up
    assert sorted(os.listdir(tmp_path / "work")) == ["s.toml"]


# ======================================================================================================
# The local pool's workers die with rhi sweep
# ======================================================================================================
def test_the_local_pool_s_workers_die_with_a_killed_sweep(tmp_path):
    """A worker stuck in native code holding the GIL (Dask's own watch on its parent cannot run) still dies
    when rhi sweep is SIGKILLed: every process started under it is gone within a few seconds."""
    import signal
    import subprocess
    import sys
    import time

    import psutil

    from tests.sweep_files import sweep_file

    for name in ("work", "tmp", "cache"):
        (tmp_path / name).mkdir()
    sweep_file(tmp_path / "work" / "s.toml", grid={"conditions.left": [-0.1]}, task="stuck_outcome", trials=1,
               workers=1)
    marker = tmp_path / "stuck"
    env = {**ENV, "TMPDIR": str(tmp_path / "tmp"), "RHI_CACHE": str(tmp_path / "cache"),
           "RHI_TEST_STUCK_MARKER": str(marker)}
    sweep = subprocess.Popen([sys.executable, "-m", "rhi", "sweep", "--config", "s.toml", "--out", "out"],
                             cwd=tmp_path / "work", env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    descendants = []
    try:
        deadline = time.monotonic() + 60
        while not marker.exists() and time.monotonic() < deadline and sweep.poll() is None:
            time.sleep(0.1)
        assert marker.exists(), "the trial never started"
        descendants = psutil.Process(sweep.pid).children(recursive=True)
        assert descendants, "no worker process under rhi sweep"
        sweep.send_signal(signal.SIGKILL)
        sweep.wait()
        deadline = time.monotonic() + 5
        alive = descendants
        while alive and time.monotonic() < deadline:
            time.sleep(0.05)
            alive = [p for p in descendants if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]
        assert not alive, f"ran on after rhi sweep was killed: {[' '.join(p.cmdline())[:80] for p in alive]}"
    finally:
        for process in descendants:
            try:
                process.kill()
            except psutil.Error:
                pass
        if sweep.poll() is None:
            sweep.kill()


# ======================================================================================================
# The manifest: rhi removes or writes over only files it can prove it wrote
# ======================================================================================================
def test_an_experiment_output_is_published_with_a_manifest_of_every_file(tmp_path):
    import hashlib

    from rhi.master.outputs import files

    out = tmp_path / "run"
    with files.output_folder(out, force=False) as staging:
        (staging / "summary.csv").write_text("a,b\n1,2\n")
        (staging / "figures").mkdir()
        (staging / "figures" / "a.png").write_bytes(b"\x89PNG")
    manifest = json.loads((out / ".rhi-manifest.json").read_text())
    assert manifest["command"] == "rhi experiment" and manifest["folders"] == ["figures"]
    assert manifest["files"] == {name: {"bytes": (out / name).stat().st_size,
                                        "sha256": hashlib.sha256((out / name).read_bytes()).hexdigest()}
                                 for name in ("figures/a.png", "summary.csv")}
    assert files.foreign_entries(out) == []  # all of it proven: --force may replace it
    (out / "figures" / "a.png").write_bytes(b"\x89PNG edited")
    (out / "figures" / "b.png").write_bytes(b"mine")
    assert files.foreign_entries(out) == ["figures/a.png (changed since rhi wrote it)", "figures/b.png"]


def test_an_older_output_without_a_manifest_is_never_replaced(tmp_path):
    (tmp_path / "work" / "results").mkdir(parents=True)
    (tmp_path / "work" / "results" / "run.json").write_text('{"command": "rhi experiment", "figures": []}')
    before = snapshot(tmp_path / "work")
    done = rhi(tmp_path, "experiment", "--quick", "--out", "results", "--force")
    refused(done, "output folder results is not an earlier rhi experiment output (it holds run.json)")
    assert snapshot(tmp_path / "work") == before


def test_a_phenomenon_report_file_rhi_did_not_write_is_never_written_over(tmp_path):
    (tmp_path / "work" / "out").mkdir(parents=True)
    (tmp_path / "work" / "out" / "distance.csv").write_text("my own table\n")
    before = snapshot(tmp_path / "work")
    done = rhi(tmp_path, "phenomenon", "distance", "--out", "out", "--force")
    refused(done, "output folder out: distance.csv would be written over but is not what rhi phenomenon wrote there")
    assert snapshot(tmp_path / "work") == before


# -- the docs page states the limits the code applies -------------------------------------------------
def test_docs_safety_states_the_code_s_limits():
    from rhi.components.archives import LIMITS
    from rhi.components.vision import checkpoint
    from rhi.master import config
    from rhi.master.export import ssp_package
    from rhi.master.outputs import out_file
    from rhi.master.sweeps import plan, runner

    page = (REPO / "docs" / "safety.md").read_text()
    table = page.partition("<!-- limits table")[2].split("\n\n")[0]
    values = [line.split("|")[2].strip().split()[0] for line in table.splitlines() if line.startswith("| ")][1:]
    assert values == [str(v) for v in (
        LIMITS.members, LIMITS.member_bytes, LIMITS.total_bytes, f"{LIMITS.ratio:g}", checkpoint.MAX_HIDDEN,
        checkpoint.MAX_CHANNELS, checkpoint.MAX_STAGES, checkpoint.MAX_RESOLUTION, config.MAX_CONFIG_BYTES,
        config.MAX_DEPTH, plan.MAX_POINTS, ssp_package.MAX_STEPS, f"{runner.CONNECT_TIMEOUT_S:g}",
        f"{runner.PROBE_S:g}", runner.MAX_HANDSHAKE_BYTES, config.MAX_THREADS, out_file.NAME_MARGIN)]
    assert f"over {LIMITS.ratio_floor} bytes" in table and "task" in page and "rhi --version" in page
    assert all(key in page for key in config.INFINITE_KEYS)


def test_rhi_version_prints_the_installed_version(tmp_path):
    from importlib import metadata

    done = rhi(tmp_path, "--version")
    assert done.returncode == 0 and done.stdout.strip() == f"rhi {metadata.version('rhi')}"


# -- late validation ----------------------------------------------------------------------------------
@pytest.mark.parametrize("key, value, says", [
    ("experiment.resolution", 12, r"\[train\]: .*resolution = 12 does not fit"),
    ("train.preset", "huge", r"\[train\]: train setting preset = 'huge' is unknown"),
    ("body.substeps", 0, r"body\.substeps: body\.substeps = 0 is outside its range \[1, 10000\]"),
    ("stimulus.period", 0.0, r"stimulus\.period: stimulus\.period = 0\.0 is outside its range"),
])
def test_settings_are_checked_before_the_staging_folder_and_training(tmp_path, monkeypatch, key, value, says):
    from rhi.master import config as configuration
    from rhi.master.tasks.illusion.publish import run_into

    import tempfile

    def no_staging(*args, **kwargs):
        raise AssertionError("a staging folder was made before the settings were checked")

    monkeypatch.setenv("RHI_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(tempfile, "mkdtemp", no_staging)
    with pytest.raises((ConfigError, ValueError), match=says):
        run_into("out", configuration.load(overrides={key: value}, quick=True))
    assert os.listdir(tmp_path) == []  # no cache made, nothing trained, no staging


def test_a_bad_checkpoint_is_found_before_the_other_decoder_is_trained(tmp_path, monkeypatch):
    from rhi.components.vision.checkpoint import CheckpointError
    from rhi.master import config as configuration
    from rhi.master.tasks.illusion.publish import run_into

    monkeypatch.setenv("RHI_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    (tmp_path / "vae.pt").write_text("not a checkpoint")
    config = configuration.load(overrides={"decoder.vae_checkpoint": str(tmp_path / "vae.pt")}, quick=True)
    with pytest.raises(CheckpointError, match="not a decoder checkpoint"):
        run_into("out", config)
    assert sorted(os.listdir(tmp_path)) == ["vae.pt"]  # no cache made, no conv trained, no staging
