"""Experiment outputs: summary statistics by hand, the staging folder, refusal of foreign content."""
import numpy as np
import pytest

from rhi.master.outputs import files, tables as outputs
from rhi.master.cosim import ConfigError
from rhi.master.tasks.illusion import Trial, plan, trial_seed
from rhi.master.config import load
from rhi.master.tasks.illusion.measures import end_of_trial, half_time


def test_plan_covers_the_protocol_with_stable_seeds():
    trials = plan(load())
    assert len(trials) == 2 * 3 * 2 * 5
    assert len({(t.decoder, t.condition, t.stimulation, t.index) for t in trials}) == 60
    # Both decoders see the same delays: the seed does not depend on the decoder.
    conv = [t.seed for t in trials if t.decoder == "conv"]
    vae = [t.seed for t in trials if t.decoder == "vae"]
    assert conv == vae and len(set(conv)) == 30
    assert trial_seed(0, "left", "sync", 0) == trial_seed(0, "left", "sync", 0) != trial_seed(1, "left", "sync", 0)


def test_summary_by_hand():
    trials = [Trial("conv", "left", "sync", i, i, -0.15, 0.0, 0.1) for i in range(3)] + \
             [Trial("conv", "right", "sync", 0, 9, 0.15, 0.0, 0.1)]
    final = {"drift_cm": np.array([-1.0, -2.0, -3.0, 4.0]), "force_x_n": np.array([-0.1, -0.2, -0.6, 0.5]),
             "gamma": np.array([0.9, 1.0, 0.95, 1.0]),
             "action_accel_mean_x_m_s2": np.array([-0.01, -0.02, -0.06, 0.03]),
             "action_accel_x_m_s2": np.array([-0.02, -0.02, -0.05, 0.04])}
    rows = outputs.summary(trials, final)
    # sd with ddof = 1: sqrt(((0.1)^2 + 0 + 0.2^2 + ...)/2); the action measure's columns after the old ones
    assert rows[0] == ["conv", "left", "sync", 3, "-2", "1", "-0.3", "0.264575", "0.95",
                       "-0.03", "0.0264575", "-0.03", "0.0173205"]
    assert rows[1] == ["conv", "right", "sync", 1, "4", "0", "0.5", "0", "1", "0.03", "0", "0.04", "0"]
    assert outputs.SUMMARY_COLUMNS[:9] == ["decoder", "condition", "stimulation", "n_trials", "drift_cm_mean",
                                           "drift_cm_sd", "force_n_mean", "force_n_sd", "gamma_final_mean"]
    assert len(outputs.SUMMARY_COLUMNS) == len(rows[0])


def test_end_of_trial_measures_by_hand():
    """The action measure's trial mean leaves out row 0 (no step yet); the drift's half time is the first
    time it reaches half its final value, by size; NaN when it ends at 0."""
    times = np.array([0.0, 0.02, 0.04, 0.06])
    per_step = {"drift_cm": np.array([[0.0, 0.0, 0.0], [-0.5, 0.1, 0.3], [-0.9, 0.3, -0.1], [-1.0, 0.4, 0.0]]),
                "action_accel_x_m_s2": np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [2.0, 2.0, 0.0],
                                                 [6.0, -1.0, 0.0]]),
                # the last touch: at 0.02 s in trials 0 and 2, none in trial 1
                "tactile_time_s": np.array([[-np.inf] * 3, [0.02, -np.inf, 0.02], [0.02, -np.inf, 0.02],
                                            [0.02, -np.inf, 0.02]])}
    final = end_of_trial(times, per_step)
    np.testing.assert_allclose(final["action_accel_mean_x_m_s2"], [3.0, 1.0, 1.0], rtol=1e-15)
    np.testing.assert_array_equal(final["action_accel_x_m_s2"], [6.0, -1.0, 0.0])
    np.testing.assert_array_equal(final["drift_cm"], [-1.0, 0.4, 0.0])
    half = final["drift_half_time_s"]
    assert half[0] == 0.02 and half[1] == 0.04 and np.isnan(half[2])
    np.testing.assert_array_equal(half_time(times, per_step["drift_cm"][:, :2]), half[:2])
    # after the touch at 0.02 s: trial 0's drift grows (-0.5 -> -1.0), never halving; trial 1 had no touch;
    # trial 2's falls from 0.3 to -0.1 (ratio -1/3 <= 1/2) at 0.04 s, 0.02 s after it
    decay = final["drift_half_decay_s"]
    assert np.isnan(decay[0]) and np.isnan(decay[1]) and decay[2] == 0.04 - 0.02


def test_trials_csv_is_tidy():
    trials = [Trial("vae", "center", "async", 0, 5, 0.0, 0.0, 1.0), Trial("vae", "center", "async", 1, 6, 0.0, 0.0, 1.0)]
    text = outputs.trials_csv(trials, np.array([0.0, 0.02]), {"drift_cm": np.array([[0.0, 0.0], [0.1, -0.1]])})
    assert text.splitlines() == ["decoder,condition,stimulation,trial,seed,step,time_s,drift_cm",
                                 "vae,center,async,0,5,0,0,0", "vae,center,async,0,5,1,0.02,0.1",
                                 "vae,center,async,1,6,0,0,0", "vae,center,async,1,6,1,0.02,-0.1"]


def test_trials_csv_formats_every_number_as_csv_writer_and_format_would():
    """The row-at-a-time formatting against the csv module and f"{x:.6g}", value by value."""
    import csv
    import io

    rng = np.random.default_rng(3)
    values = rng.standard_normal((4, 3, 2)) * 10.0 ** rng.integers(-320, 300, (4, 3, 2))
    values[0, 0] = [np.nan, np.inf]
    values[1, 1] = [-np.inf, -0.0]
    values[2, 2] = [1e-7, 123456789.0]
    per_step = {"a": values[..., 0], "b": values[..., 1]}
    times = np.array([0.0, 0.02, 1 / 3, 30.0])
    trials = [Trial("conv", "left", "sync", i, 2**62 + i, -0.1, 0.0, 1.0) for i in range(3)]
    expected = io.StringIO()
    writer = csv.writer(expected, lineterminator="\n")
    writer.writerow(outputs.TRIAL_KEYS + ["step", "time_s", "a", "b"])
    for b, trial in enumerate(trials):
        for step, time in enumerate(times):
            writer.writerow([trial.decoder, trial.condition, trial.stimulation, trial.index, trial.seed, step,
                             f"{time:.6g}", f"{per_step['a'][step, b]:.6g}", f"{per_step['b'][step, b]:.6g}"])
    assert outputs.trials_csv(trials, times, per_step) == expected.getvalue()


def test_staging_refuses_foreign_content_and_publishes_whole(tmp_path):
    """--force replaces an earlier output of rhi experiment, never a folder holding anything else."""
    from rhi.master.outputs.manifest import Manifest

    out = tmp_path / "run"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    with pytest.raises(ConfigError, match=r"exists and is not empty \(use --force"):
        with files.output_folder(out, force=False):
            pass
    with pytest.raises(ConfigError, match=r"is not an earlier rhi experiment output \(it holds notes\.txt\)"):
        with files.output_folder(out, force=True):
            pass
    (out / "notes.txt").unlink()
    (out / "run.json").write_text('{"command": "rhi experiment", "figures": ["a.png"]}')
    (out / "figures").mkdir()
    (out / "figures" / "a.png").write_bytes(b"png")
    Manifest.of(out, files.OUTPUT_COMMAND).save()  # as an earlier run wrote it
    with files.output_folder(out, force=True) as staging:
        (staging / "summary.csv").write_text("x\n")
        assert (out / "run.json").exists()  # untouched until the run is complete
    assert sorted(p.name for p in out.iterdir()) == [".rhi-manifest.json", "summary.csv"]
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_staging_needs_an_existing_parent(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        files.check_output(tmp_path / "no" / "such", force=False)
    (tmp_path / "file").write_text("")
    with pytest.raises(ConfigError, match="is not a folder"):
        files.check_output(tmp_path / "file", force=False)


def test_a_failing_trial_is_dropped_and_the_rest_rerun():
    """The batch is rerun without the trials a component blames; a failure blaming none stops the run."""
    from rhi.master.cosim import SimulationError
    from rhi.master.tasks.illusion import without_failures

    trials = plan(load())[:6]
    bad = {trials[1], trials[4]}
    calls = []

    def run_trials(batch):
        calls.append(list(batch))
        blamed = [position for position, trial in enumerate(batch) if trial in bad]
        if blamed:
            raise SimulationError("body", 0.12, "output hand_y is nan", trials=blamed[:1])
        return "result"

    result, kept, failures = without_failures(run_trials, trials)
    assert result == "result" and kept == [t for t in trials if t not in bad]
    assert set(failures) == bad and all("hand_y is nan" in e and "t = 0.12 s" in e for e in failures.values())
    assert len(calls) == 3  # one failure at a time, then the clean batch

    def run_all_fail(batch):
        raise SimulationError("decoder", 0.0, "out of memory")

    with pytest.raises(SimulationError, match="out of memory"):
        without_failures(run_all_fail, trials)


def test_atomic_write_is_whole_or_absent_and_ordinary(tmp_path):
    target = tmp_path / "a.txt"
    files.atomic_write(target, "é\n")
    files.atomic_write(tmp_path / "b.bin", b"\x00\x01")
    files.atomic_write(tmp_path / "c.bin", lambda file: file.write(b"written by a function"))
    assert target.read_bytes() == "é\n".encode() and (tmp_path / "b.bin").read_bytes() == b"\x00\x01"
    assert (tmp_path / "c.bin").read_bytes() == b"written by a function"
    assert target.stat().st_mode & 0o777 == 0o666 & ~files.umask()  # not mkstemp's private 0600

    def fails(file):
        file.write(b"half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        files.atomic_write(target, fails)
    assert target.read_text() == "é\n"  # the old file, whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.bin", "c.bin"]  # no temporary left


def test_cells_and_sample_sd_by_hand():
    trials = [Trial("conv", c, "sync", i, i, 0.0, 0.0, 0.1) for c, i in (("left", 0), ("right", 0), ("left", 1))]
    assert outputs.cells(trials) == {("conv", "left", "sync"): [0, 2], ("conv", "right", "sync"): [1]}
    mean, sd = outputs.mean_sd(np.array([[1.0, 2.0], [3.0, 6.0]]), axis=1)
    np.testing.assert_allclose(mean, [1.5, 4.5])
    np.testing.assert_allclose(sd, [np.sqrt(0.5), np.sqrt(4.5)])  # ddof 1: (x - mean)^2 summed over n - 1
    assert outputs.mean_sd([7.0]) == (7.0, 0.0) and outputs.mean_sd([]) == (None, None)


def test_run_json_has_one_writer(tmp_path):
    """Every command's run.json is written by rhi.master.outputs.provenance.write_run_record and nothing else: no
    other module of rhi names run.json beside a write; the writer's file reads back as the record, whole."""
    import json
    import re
    from pathlib import Path

    from rhi.master.outputs.provenance import write_run_record

    root = Path(__file__).resolve().parents[1]
    writes = re.compile(r"run\.json.*(atomic_write|write_text|write_bytes|open\()|(atomic_write|write_text|open\().*run\.json")
    found = [f"{path.relative_to(root)}:{number}" for folder in ("master", "rhi") for path in (root / folder).rglob("*.py")
             if path.name != "provenance.py"
             for number, line in enumerate(path.read_text().splitlines(), 1)
             if writes.search(line) and "read_text" not in line and "json.loads" not in line]
    assert not found, found
    write_run_record(tmp_path, {"command": "rhi test", "path": tmp_path, "values": [1.5, float("nan")]})
    record = json.loads((tmp_path / "run.json").read_text())
    assert record["path"] == str(tmp_path) and record["values"][0] == 1.5 and record["command"] == "rhi test"
