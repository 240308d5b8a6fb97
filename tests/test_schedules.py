"""Stimulation schedules against hand computation: the events of a block schedule, vision only, the stroke's
timing, a hidden rubber arm, the drift at probe times (from trials.csv's rows), and the refusals, one line each."""
import csv
import subprocess
import sys

import numpy as np
import pytest
from test_stimulus import run_stimulus

from rhi.components.body.camera import Camera, ball_alpha, composite, render
from rhi.components.stimulus import block_rows
from rhi.master import config as configuration
from rhi.master.config import protocol
from rhi.master.cosim import ConfigError
from rhi.master.tasks.illusion import wiring
from rhi.master.outputs.tables import probe_name
from rhi.master.tasks.illusion.measures import probes
from tests.in_process import rhi_in_process

STEP = 0.02


def changes(column):
    """The values a per-step output takes on, in order, each when it first appears (finite only)."""
    fresh = np.isfinite(column[1:]) & (column[1:] != column[:-1])
    return column[1:][fresh].tolist()


def test_events_of_a_block_schedule_by_hand():
    # period 1 s; blocks [0, 3.5] and [5, 7]: touches at 1, 2, 3 and 6, 7 (start + k period, k >= 1, up to the end)
    out = run_stimulus(8.0, 2, period=1.0, delay_min=0.3, delay_max=0.3, blocks=block_rows([[0, 3.5], [5, 7]]))
    assert changes(out["visual_time"][:, 0]) == [1.0, 2.0, 3.0, 6.0, 7.0]
    assert np.allclose(changes(out["tactile_time"][:, 0]), [1.3, 2.3, 3.3, 6.3, 7.3], atol=1e-12)
    assert np.isneginf(out["visual_time"][49, 0]) and out["visual_time"][50, 0] == 1.0  # at the step ending at 1 s
    assert out["visual_time"][299, 0] == 3.0 and out["visual_time"][300, 0] == 6.0     # nothing in the pause


def test_a_block_starting_off_the_period_grid_and_stop_time():
    # period 2 s, block [2.5, 20], stop_time 9: touches at 4.5, 6.5, 8.5 (10.5 is after stop_time)
    out = run_stimulus(12.0, 1, period=2.0, delay_max=0.0, blocks=block_rows([[2.5, 20.0]]), stop_time=9.0)
    assert changes(out["visual_time"][:, 0]) == [4.5, 6.5, 8.5]


def test_the_default_schedule_is_one_block_over_the_trial_bit_for_bit():
    default = run_stimulus(20.0, 3, delay_max=1.0, seed=[1, 2, 3])
    explicit = run_stimulus(20.0, 3, delay_max=1.0, seed=[1, 2, 3], blocks=block_rows([[0.0, np.inf]]),
                            stroke_duration=2.0)
    for name in default:
        assert default[name].tobytes() == explicit[name].tobytes(), name


def test_vision_only_has_the_visual_events_and_no_tactile_one():
    touched = run_stimulus(10.0, 2, period=1.0, seed=[4, 5])
    seen = run_stimulus(10.0, 2, period=1.0, seed=[4, 5], touch=[False, True])
    assert np.array_equal(seen["visual_time"], touched["visual_time"])
    assert np.all(np.isneginf(seen["tactile_time"][:, 0]))
    assert np.array_equal(seen["tactile_time"][:, 1], touched["tactile_time"][:, 1])
    assert np.array_equal(seen["ball"], touched["ball"])


def test_stroke_timing_by_hand():
    # 500 ms strokes with 500 ms pauses: period 1 s, stroke 0.5 s, the ball 0.2 m away before a stroke
    out = run_stimulus(3.0, 1, period=1.0, stroke_duration=0.5, ball_distance=0.2, target=[[-0.3, 0.5]])
    away = out["ball"][:, 0, 1] - 0.5
    expected = {0.0: 0.2, 0.2: 0.2, 0.5: 0.2, 0.7: 0.12, 0.9: 0.04, 1.0: 0.0, 1.2: 0.0, 1.5: 0.2, 1.8: 0.08, 2.0: 0.0}
    for time, distance in expected.items():  # before the first stroke it waits; between strokes it rests on the hand
        assert away[round(time / STEP)] == pytest.approx(distance, abs=1e-12), time


def test_a_hidden_rubber_arm_leaves_the_ball_alone():
    camera = Camera(resolution=32)
    camera.instantiate(2)
    camera.set("arm_visible", [True, False])
    ball = np.array([[-0.3, 0.6], [-0.3, 0.6]])
    camera.set("ball", ball)
    camera.enter_initialization_mode()
    camera.exit_initialization_mode()
    image = camera.get("image")
    assert np.array_equal(image[0], render([camera.get("arm_pose")[0]], 32, ball[:1])[0])
    alone = composite(np.zeros((32, 32), np.float32), ball_alpha(ball[1], 32))
    assert np.array_equal(image[1], alone) and image[1].max() > 0


def test_schedule_keys_reach_the_trials_and_parameters(tmp_path):
    path = tmp_path / "protocol.toml"
    path.write_text('[experiment]\nconditions = ["right", "none"]\nstimulations = ["sync", "vision"]\ntrials = 1\n'
                    'probe_times = [1.0, 2.5]\n[conditions]\nnone = 0.15\n[rubber_arm]\nhidden_conditions = ["none"]\n'
                    '[stimulations.vision]\ntouch = false\nblocks = [[0, 2.0], [3.0, 6.0]]\n[stimulus]\nperiod = 1.0\n'
                    'stroke_duration = 0.5\n')
    config = configuration.load(path, overrides={"experiment.decoders": ["conv"]})
    trials = protocol.plan(config)
    given = wiring.parameters(trials, config)
    assert [(t.condition, t.stimulation, t.touch, t.arm_visible) for t in trials] == [
        ("right", "sync", True, True), ("right", "vision", False, True),
        ("none", "sync", True, False), ("none", "vision", False, False)]
    assert given["stimulus.touch"].tolist() == [True, False, True, False]
    assert given["camera.arm_visible"].tolist() == [True, True, False, False]
    assert given["stimulus.blocks"].shape == (4, 2, 2)  # as many rows as the fullest schedule
    assert given["stimulus.blocks"][1, :2].tolist() == [[0.0, 2.0], [3.0, 6.0]]
    assert given["stimulus.blocks"][0, 0].tolist() == [0.0, np.inf] and np.isnan(given["stimulus.blocks"][0, 1:]).all()
    assert given["stimulus.stroke_duration"] == 0.5


def test_probe_reads_the_first_step_at_or_after_its_time():
    times = np.arange(6) * 0.02
    drift = np.arange(12.0).reshape(6, 2)
    read = probes(times, drift, [0.0, 0.04, 0.05, 0.1])
    assert list(read) == ["drift_at_0s_cm", "drift_at_0.04s_cm", "drift_at_0.05s_cm", "drift_at_0.1s_cm"]
    assert [read[key].tolist() for key in read] == [[0, 1], [4, 5], [6, 7], [10, 11]]
    assert probe_name(60) == "drift_at_60s_cm"


BAD = [
    ("[stimulus]\nstroke_duration = 3.0\n", "stimulus.stroke_duration = 3 s must be positive and at most"),
    ("[stimulations.sync]\nblocks = [[0, 10], [5, 20]]\n", "stimulations.sync.blocks: block [5, 20] overlaps"),
    ("[stimulations.sync]\nblocks = [[4, 2]]\n", "block [4, 2] needs 0 <= start < end"),
    ("[stimulations.sync]\nblocks = [[0, 1]]\n", "is shorter than stimulus.period = 2 s"),
    ("[stimulations.sync]\nblocks = [[40, 50]]\n", "starts at or after the trial's end, 30 s"),
    ("[stimulations.sync]\nblocks = [0, 10]\n", "must be a pair [start_s, end_s]"),
    ("[stimulations.sync]\ntouch = 1\n", "stimulations.sync.touch = 1 must be a bool"),
    ("[experiment]\nprobe_times = [10, 31]\n", "experiment.probe_times: 31 s is beyond the trial, which lasts 30 s"),
    ("[experiment]\nprobe_times = [10, 5]\n", "must be strictly increasing"),
    ("[rubber_arm]\nhidden_conditions = [\"nowhere\"]\n", "'nowhere' is not defined in [conditions]"),
    # readings and the rubber arm's visibility (tests/test_readings.py)
    ("[readings]\ntimes = [10, 5]\n", "readings.times = [10, 5] must be strictly increasing"),
    ("[readings]\ntimes = [10, 12]\nduration = 3.0\n", "the reading at 10 s lasts 3 s and overlaps the one at 12 s"),
    ("[readings]\ntimes = [-1]\n", "readings.times: -1 s is not within the trial"),
    ("[readings]\ntimes = [nan]\n", "must be a list of finite times"),
    ("[readings]\ntimes = [inf]\n", "must be a list of finite times"),
    ("[readings]\nduration = -2.0\n", "readings.duration = -2.0 must be a finite time >= 0"),
    ("[readings]\nduration = nan\n", "readings.duration = nan must be a finite number"),  # the loader's own check
    ("[readings]\nhide_arm = 1\n", "readings.hide_arm = 1 must be a bool"),  # the loader's own type check
    ("[rubber_arm]\nhidden_times = [[0, 10], [5, 20]]\n", "rubber_arm.hidden_times: [5, 20] overlaps"),
    ("[rubber_arm]\nhidden_times = [[5, inf]]\n", "must be a pair [start_s, end_s] of finite numbers"),
    ("[rubber_arm]\nhidden_times = [[-5, 2]]\n", "needs 0 <= start < end"),
    ("[stimulations.sync]\nblocks = [[0, nan]]\n", "must be a pair [start_s, end_s] of finite numbers"),
]


@pytest.mark.parametrize("text, fragment", BAD)
def test_bad_schedules_are_refused_in_one_line(tmp_path, text, fragment):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as error:
        configuration.load(path)
    assert fragment in str(error.value) and "\n" not in str(error.value)


def test_the_command_refuses_a_bad_schedule_with_status_2(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text("[stimulations.sync]\nblocks = [[0, 10], [5, 20]]\n")
    done = subprocess.run([sys.executable, "-m", "rhi", "experiment", "--config", str(path), "--out",
                           str(tmp_path / "out")], capture_output=True, text=True, timeout=300)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1 and "overlaps" in done.stderr
    assert not (tmp_path / "out").exists()


def test_probes_are_the_per_step_drift_of_trials_csv(tmp_path, quick_cache):
    path = tmp_path / "probes.toml"
    path.write_text('[experiment]\ndecoders = ["conv"]\nconditions = ["left"]\nstimulations = ["sync", "vision"]\n'
                    'steps = 150\nprobe_times = [1.0, 2.01]\n[stimulations.vision]\ntouch = false\n'
                    'blocks = [[0.5, 2.6]]\n')
    done = rhi_in_process(["experiment", "--quick", "--config", str(path), "--out", str(tmp_path / "out")], tmp_path,
                          {"RHI_CACHE": str(quick_cache)}, timeout=300)
    assert done.status == 0, done.stderr[-2000:]
    with open(tmp_path / "out" / "summary.csv") as file:
        summary = list(csv.DictReader(file))
    with open(tmp_path / "out" / "trials.csv") as file:
        rows = list(csv.DictReader(file))
    assert list(summary[0])[-4:] == ["drift_at_1s_cm_mean", "drift_at_1s_cm_sd", "drift_at_2.01s_cm_mean",
                                     "drift_at_2.01s_cm_sd"]
    for cell in summary:  # one trial per cell: the mean is the trial's drift at the first step at or after t
        mine = {int(row["step"]): row for row in rows if row["stimulation"] == cell["stimulation"]}
        assert cell["drift_at_1s_cm_mean"] == mine[50]["drift_cm"]
        assert cell["drift_at_2.01s_cm_mean"] == mine[101]["drift_cm"]
    vision = [row for row in rows if row["stimulation"] == "vision"]
    assert {row["tactile_time_s"] for row in vision} == {"-inf"}
    assert sorted({float(row["visual_time_s"]) for row in vision}) == [-np.inf, 2.5]  # the block's one touch


def test_the_ball_rests_between_blocks_and_waits_before_a_late_first_block():
    out = run_stimulus(8.0, 1, period=1.0, ball_distance=0.2, target=[[-0.3, 0.5]], blocks=block_rows([[0, 2], [5, 7]]))
    away = out["ball"][:, 0, 1] - 0.5
    assert away[round(3.0 / STEP)] == 0.0 and away[round(4.9 / STEP)] == 0.0  # the pause: on the hand
    assert away[round(5.5 / STEP)] == pytest.approx(0.1, abs=1e-12)  # the second block's first stroke, to t = 6
    late = run_stimulus(4.0, 1, period=1.0, ball_distance=0.2, target=[[-0.3, 0.5]], blocks=block_rows([[2.5, 4]]))
    assert late["ball"][round(2.5 / STEP), 0, 1] - 0.5 == pytest.approx(0.2, abs=1e-12)  # no touch yet: it waits
