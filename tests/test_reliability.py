"""Reliability in-process: no data loss, no traceback, no silent wrong answer.

Each defect group (the output folder, concurrent runs, checkpoints, configuration, bodies, time limits and
signals, exports, the machine's faults) reproduced in-process, where that is the fastest honest check; the
same faults through the real command line are tests/test_cli_catalogue.py.
"""
from __future__ import annotations

import errno
import math
import os
import signal
import time
import zipfile
from types import SimpleNamespace

import numpy as np
import pytest

from rhi.master.cosim import ConfigError
from rhi.master.runtime.context import RunContext

from tests.faults import Resources


@pytest.fixture(scope="module")
def resources(fault_resources) -> Resources:
    return fault_resources  # made once per test run (tests/conftest.py)


# -- data loss: --out . / "" / .. / a foreign folder with --force ----------------------------------
@pytest.mark.parametrize("out", [".", "", "..", "./", "work/..", "/"])
def test_the_working_folder_and_those_above_it_are_refused_even_with_force(tmp_path, monkeypatch, out):
    from rhi.master.outputs import files

    work = tmp_path / "work"
    work.mkdir()
    (work / "thesis.tex").write_text("precious")
    monkeypatch.chdir(work)
    with pytest.raises(ConfigError, match="working folder or a folder above it|--out is empty"):
        with files.output_folder(out, force=True):
            pass
    assert (work / "thesis.tex").read_text() == "precious" and sorted(os.listdir(tmp_path)) == ["work"]


def test_force_replaces_only_rhi_s_own_output(tmp_path):
    from rhi.master.outputs import files
    from rhi.master.outputs.manifest import Manifest

    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "run.json").write_text('{"command": "my own tool"}')  # a run.json, but not ours
    with pytest.raises(ConfigError, match="not an earlier rhi experiment output"):
        files.check_output(foreign, force=True)
    ours = tmp_path / "ours"
    ours.mkdir()
    (ours / "run.json").write_text('{"command": "rhi experiment", "figures": ["a.png"]}')
    (ours / "figures").mkdir()
    (ours / "figures" / "a.png").write_text("png")
    Manifest.of(ours, files.OUTPUT_COMMAND).save()  # as the earlier run wrote it
    (ours / "figures" / "notes.txt").write_text("mine")  # added by the user: not ours
    with pytest.raises(ConfigError, match=r"it holds figures/notes\.txt"):
        files.check_output(ours, force=True)
    (ours / "figures" / "notes.txt").unlink()
    (ours / "run.json").write_text('{"command": "rhi experiment", "edited": true}')  # edited by the user
    with pytest.raises(ConfigError, match=r"it holds run\.json \(changed since rhi wrote it\)"):
        files.check_output(ours, force=True)
    (ours / "run.json").write_text('{"command": "rhi experiment", "figures": ["a.png"]}')
    with files.output_folder(ours, force=True) as staging:
        (staging / "summary.csv").write_text("new\n")
    assert sorted(os.listdir(ours)) == [".rhi-manifest.json", "summary.csv"]
    assert sorted(os.listdir(tmp_path)) == ["foreign", "ours"]


# -- a concurrent run: the lock, and publish's re-check ----------------------------------------------
def test_a_second_run_into_the_same_folder_is_refused_while_the_first_holds_it(tmp_path):
    from rhi.master.outputs import files

    out = tmp_path / "race"
    with files.output_folder(out, force=False) as staging:
        (staging / "summary.csv").write_text("first\n")
        with pytest.raises(ConfigError, match="another rhi run is writing"):
            with files.output_folder(out, force=True):
                pass
    assert (out / "summary.csv").read_text() == "first\n"
    assert sorted(os.listdir(tmp_path)) == ["race"]  # the lock file went with the run


def test_publish_leaves_alone_what_appeared_meanwhile(tmp_path):
    from rhi.master.outputs import files

    out = tmp_path / "race"
    with pytest.raises(ConfigError, match="appeared while this run went on|written by something else"):
        with files.output_folder(out, force=True) as staging:
            (staging / "summary.csv").write_text("second\n")
            out.mkdir()  # another program (not rhi: rhi would have met the lock) writes DIR meanwhile
            (out / "summary.csv").write_text("first\n")
    assert (out / "summary.csv").read_text() == "first\n" and sorted(os.listdir(tmp_path)) == ["race"]


# -- a checkpoint of the wrong kind ---------------------------------------------------------------------
def test_a_vae_checkpoint_in_the_conv_slot_is_refused_before_any_work(resources):
    from rhi.components.vision.checkpoint import CheckpointError
    from rhi.master import config as configuration
    from rhi.master.decoders.cache import check_decoders, decoder_component

    config = configuration.load(overrides={"decoder.conv_checkpoint": resources.vae, "experiment.decoders": ["conv"]},
                                quick=True)
    with pytest.raises(CheckpointError, match="a vae decoder, given as the conv decoder"):
        check_decoders(config)
    with pytest.raises(CheckpointError, match="a vae decoder, given as the conv decoder"):
        decoder_component("conv", resources.vae, config)


# -- duplicates in the protocol's lists ---------------------------------------------------------------
@pytest.mark.parametrize("key, value", [("decoders", ["conv", "conv"]), ("conditions", ["left", "left"]),
                                        ("stimulations", ["sync", "async", "sync"])])
def test_a_list_naming_an_entry_twice_is_refused_naming_the_key(key, value):
    from rhi.master import config as configuration

    with pytest.raises(ConfigError, match=rf"experiment\.{key} lists {value[0]} more than once"):
        configuration.load(overrides={f"experiment.{key}": value})


# -- a cell whose every trial failed ----------------------------------------------------------------
def test_a_cell_without_trials_has_an_empty_row_and_no_bar(tmp_path):
    from rhi.master.tasks.illusion import Trial
    from rhi.master.outputs import figures, tables

    planned = [Trial("conv", c, s, 0, 0, 0.0, 0.0, 0.1) for c in ("left", "center") for s in ("sync", "async")]
    kept = [t for t in planned if (t.condition, t.stimulation) != ("center", "sync")]
    steps = np.linspace(0, 1, 5)[:, None] * np.array([[1.0, 2.0, 3.0]])
    from rhi.master.tasks.illusion.measures import end_of_trial

    per_step = {"drift_cm": steps, "force_x_n": steps, "gamma": steps / 3, "action_accel_x_m_s2": steps,
                "tactile_time_s": np.full_like(steps, -np.inf)}  # no touch: no half-decay
    times = np.linspace(0, 1, 5)
    final = end_of_trial(times, per_step)
    rows = tables.summary(kept, final, planned=tables.cells(planned))
    assert [row[:4] for row in rows] == [["conv", "left", "sync", 1], ["conv", "left", "async", 1],
                                         ["conv", "center", "sync", 0], ["conv", "center", "async", 1]]
    assert rows[2][4:] == [""] * (len(tables.SUMMARY_COLUMNS) - 4)
    written = figures.write_all(tmp_path, kept, times, per_step, final, None)
    assert "a_drift_final.png" in written


def test_a_decoder_whose_whole_batch_failed_costs_only_its_trials(monkeypatch):
    """A failure blaming no trial ends that decoder's batch; the other decoder's trials still run."""
    from rhi.master.cosim import SimulationError
    from rhi.master import config as configuration
    from rhi.master.tasks.illusion import runner

    config = configuration.load(quick=True)

    def fake_run_batch(decoder, batch, config, body, progress):
        if batch[0].decoder == "conv":
            raise SimulationError("decoder", 0.0, "out of memory")
        return SimpleNamespace(times=np.arange(3.0))

    monkeypatch.setattr(runner, "run_batch", fake_run_batch)
    monkeypatch.setattr("rhi.master.decoders.cache.decoder_component", lambda kind, path, config, *how, **where: None)
    monkeypatch.setattr(runner, "measures", lambda result, model=None: {"drift_cm": np.zeros((3, 6))})
    kept, _, per_step, _, failures = runner.run(config, {"conv": "c.pt", "vae": "v.pt"}, context=RunContext(processes=1))
    assert {t.decoder for t in kept} == {"vae"} and len(failures) == 6
    assert all("out of memory" in error for error in failures.values())


# -- a hung FMU and Ctrl-C during an FMU call ------------------------------------------------------
def run_fmu(path, timeout, batch_size=4):
    from rhi.components.body.contract import BODY_CONTRACT
    from rhi.components.fmu import FMUComponent
    from rhi.master import System, simulate
    from tests.toys import Constant

    system = System([Constant("shoulder", unit="deg/s"), Constant("elbow", unit="deg/s"),
                     FMUComponent(path, "body", BODY_CONTRACT, step_timeout=timeout)],
                    [("shoulder.y", "body.u_shoulder"), ("elbow.y", "body.u_elbow")])
    return simulate(system, 0.3, 0.02, batch_size=batch_size, record=["body.q_shoulder"],
                    parameters={"shoulder.value": 0.5, "elbow.value": 0.0, "body.held": True})


@pytest.fixture
def python_sigint():
    """Python's own SIGINT handler for the test (a shell starts background jobs with SIGINT ignored, and Python
    then keeps it ignored), and whatever was there put back after."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


def test_a_step_over_the_time_limit_fails_its_trial_naming_fmu_call_and_time(resources, python_sigint):
    from rhi.master.cosim import SimulationError

    began = time.monotonic()
    # 2 s: far above a normal step's milliseconds, and above a pause of the whole test process (the FMU's Python
    # runs in it), which on a loaded 2-core machine once took a normal step past a limit of 0.5 s
    with pytest.raises(SimulationError, match=r"FMU 'HangingArmPlant' \(HangingArmPlant\.fmu\): fmi2DoStep did "
                                              r"not return within its time limit of 2 s in trial 2 at t = 0\.1 s"
                       ) as caught:
        run_fmu(resources.fmus["HangingArmPlant"], 2.0)
    assert caught.value.trials == (2,) and time.monotonic() - began < 30
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the adapter's handlers are gone


def test_ctrl_c_during_an_fmu_call_is_an_interrupt_not_a_failed_trial(resources, tmp_path, monkeypatch,
                                                                       python_sigint):
    """Python's default SIGINT handler raises KeyboardInterrupt inside the FMU's own Python code, which the FMU
    used to turn into a 'fatal' status (a failed trial, and the run went on)."""
    import threading

    marker = tmp_path / "hanging"
    monkeypatch.setenv("RHI_TEST_HANG_MARKER", str(marker))

    def interrupt():
        while not marker.exists():
            time.sleep(0.02)
        time.sleep(0.2)
        os.kill(os.getpid(), signal.SIGINT)

    threading.Thread(target=interrupt, daemon=True).start()
    with pytest.raises(KeyboardInterrupt):
        run_fmu(resources.fmus["HangingArmPlant-b"], 60.0, batch_size=3)  # a copy: its own count of instances


# -- export-body, atomically ----------------------------------------------------------------------------
def test_export_builds_beside_the_target_and_renames(tmp_path, monkeypatch):
    from rhi.master.export.body import build_fmu

    target = tmp_path / "Body.fmu"
    target.write_bytes(b"the old FMU")
    real_write = zipfile.ZipFile.write

    def full_disk(self, *args, **kwargs):
        if len(self.namelist()) > 3:
            raise OSError(errno.ENOSPC, "No space left on device", self.filename)
        return real_write(self, *args, **kwargs)

    monkeypatch.setattr(zipfile.ZipFile, "write", full_disk)
    with pytest.raises(OSError, match="No space left"):
        build_fmu(target, "native")
    assert target.read_bytes() == b"the old FMU" and sorted(os.listdir(tmp_path)) == ["Body.fmu"]
    monkeypatch.setattr(zipfile.ZipFile, "write", real_write)
    assert build_fmu(target, "native") == target and zipfile.is_zipfile(target)
    assert sorted(os.listdir(tmp_path)) == ["Body.fmu"]


@pytest.mark.parametrize("out, says", [("/proc/v.fmu", "cannot write into /proc"), ("afile.txt/v.fmu", "is not a folder"),
                                       ("existing.fmu", "is a folder"), ("", "must be a file name ending in .fmu")])
def test_unwritable_export_targets_are_refused_before_building(tmp_path, monkeypatch, out, says):
    from rhi.master.export.body import build_fmu

    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile.txt").write_text("x")
    (tmp_path / "existing.fmu").mkdir()
    with pytest.raises(ConfigError, match=says):
        build_fmu(out, "native")
    assert sorted(os.listdir(tmp_path)) == ["afile.txt", "existing.fmu"] and not os.listdir(tmp_path / "existing.fmu")


# -- inputs that used to end in a traceback ----------------------------------------------------------
def test_config_files_that_are_not_utf8_or_not_numbers_are_named(tmp_path):
    from rhi.master import config as configuration

    path = tmp_path / "c.toml"
    path.write_bytes(b"\xff\xfe[experiment]\n")
    with pytest.raises(ConfigError, match=r"is not UTF-8 text \(byte 0xff at position 0\)"):
        configuration.load(path)
    path.write_text('[experiment]\nconditions = ["far"]\n[conditions]\nfar = "very"\n')
    with pytest.raises(ConfigError, match=r"config key conditions\.far = 'very' must be a float"):
        configuration.load(path)
    path.write_text('[stimulations.slow]\ndelay_min = "x"\n')
    with pytest.raises(ConfigError, match=r"stimulations\.slow\.delay_min = 'x' must be a float"):
        configuration.load(path)


def test_resolution_and_memory_have_upper_bounds_naming_the_memory():
    from rhi.master import config as configuration

    with pytest.raises(ConfigError, match=r"experiment\.resolution must be at most 1024 pixels, got 100000 \(it "
                                          r"would need about [\d.]+ TiB of memory\)"):
        configuration.load(overrides={"experiment.resolution": 100000}, quick=True)
    with pytest.raises(ConfigError, match=r"would need about [\d.]+ [TP]iB of memory \(60 trials of 1000000000 "
                                          r"steps at 64 x 64 px\), more than this machine's"):
        configuration.load(overrides={"experiment.steps": 10 ** 9})


def test_the_decoder_cache_must_be_a_folder(tmp_path, monkeypatch):
    from rhi.master import config as configuration
    from rhi.master.decoders.cache import check_decoders

    (tmp_path / "cache").write_text("a file")
    monkeypatch.setenv("RHI_CACHE", str(tmp_path / "cache"))
    with pytest.raises(ConfigError, match=r"the decoder cache .*cache \(RHI_CACHE\) is not a folder"):
        check_decoders(configuration.load(quick=True))


def test_an_fmu_whose_binary_does_not_load_is_refused_when_opened(resources):
    from rhi.components.component import ComponentError
    from rhi.components.body.contract import BODY_CONTRACT
    from rhi.components.fmu import FMUComponent

    with pytest.raises(ComponentError, match=r"Unloadable\.fmu cannot be used: its binary binaries/linux64/ArmBody"
                                             r"\.so does not load on this machine \(.*invalid ELF header"):
        FMUComponent(resources.fmus["unloadable"], "body", BODY_CONTRACT)


def test_train_checks_its_output_before_training(tmp_path):
    from rhi.master.decoders.training import check_target

    with pytest.raises(ConfigError, match="is a folder; name the checkpoint file"):
        check_target(tmp_path)
    with pytest.raises(ConfigError, match=r"cannot write into /proc"):
        check_target("/proc/conv.pt")
    assert check_target(tmp_path / "conv.pt") == tmp_path / "conv.pt" and os.listdir(tmp_path) == []


# -- messages -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("key, value, says", [
    ("experiment.decoders", [], r"experiment\.decoders is empty"),
    ("experiment.conditions", [], r"experiment\.conditions is empty"),
    ("decoder.visual_variance", math.nan, r"config key decoder\.visual_variance = nan must be a finite number"),
    ("brain.gamma0", math.inf, r"config key brain\.gamma0 = inf must be a finite number"),
    ("experiment.scheme", "jakobi", r"experiment\.scheme = 'jakobi' is not one of gauss-seidel, jacobi"),
    ("decoder.conv_checkpoint", "/", r"decoder\.conv_checkpoint: / is a folder, not a checkpoint file"),
])
def test_named_messages(key, value, says):
    from rhi.master import config as configuration
    from rhi.master.decoders.cache import check_decoders

    with pytest.raises(ConfigError, match=says):
        check_decoders(configuration.load(overrides={key: value}))


def test_every_sweep_point_is_validated_before_the_sweep_starts(tmp_path):
    from rhi.master.sweeps import plan as sweeps

    path = tmp_path / "s.toml"
    path.write_text('[sweep]\n[sweep.grid]\n"experiment.scheme" = ["gauss-seidel", "jakobi"]\n')
    with pytest.raises(ConfigError, match=r"sweep point 1 \(experiment\.scheme=\"jakobi\"\): experiment\.scheme"):
        sweeps.load(path)
    path.write_text('[sweep]\n[sweep.grid]\n"body.substeps" = [10, 0]\n')
    with pytest.raises(ConfigError, match=r"sweep point 1 .*body\.substeps = 0 is outside its range"):
        sweeps.load(path)


def test_usage_errors_are_one_line(capsys):
    from rhi.master.commands.cli import main

    for argv in (["experiment"], ["experiment", "--trials", "many", "--out", "x"], ["fly"], []):
        with pytest.raises(SystemExit) as caught:
            main(argv)
        assert caught.value.code == 2
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("rhi") and ": error: " in lines[0], lines


def test_stale_staging_of_ours_is_cleaned_and_nothing_else(tmp_path):
    from rhi.master.outputs import files

    out = tmp_path / "run"
    ours = files._make_staging(files.check_output(out, force=False))  # as a killed run leaves it: marked ours
    (ours / "summary.csv").write_text("half")
    empty = tmp_path / ".run.abcdefgh.partial"  # killed before it was marked
    empty.mkdir()
    theirs = tmp_path / ".run.zzzzzzzz.partial"  # same pattern, not ours: left alone
    theirs.mkdir()
    (theirs / "keep.txt").write_text("mine")
    with files.output_folder(out, force=False) as staging:
        (staging / "summary.csv").write_text("whole\n")
    assert sorted(os.listdir(tmp_path)) == [".run.zzzzzzzz.partial", "run"]
    assert (theirs / "keep.txt").read_text() == "mine"
