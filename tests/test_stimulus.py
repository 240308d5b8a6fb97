"""The stimulus generator: delay distributions (KS tests), the 2 s period to the step, the ball, bad input."""
import numpy as np
import pytest
from scipy import stats

from rhi.components.component import ComponentError
from rhi.components.stimulus import Stimulus

STEP = 0.02


def run_stimulus(seconds, batch_size, **parameters):
    """Step the generator the way the master does (t on the integer tick); returns {output: (ticks + 1, B, ...)}."""
    rows = {name: np.shape(parameters[name])[-2] for name in ("blocks", "hidden") if name in parameters}
    stimulus = Stimulus(**rows)
    stimulus.instantiate(batch_size)
    for name, value in parameters.items():
        stimulus.set(name, value)
    stimulus.enter_initialization_mode()
    stimulus.exit_initialization_mode()
    ticks = round(seconds / STEP)
    names = ("visual_time", "tactile_time", "ball", "arm_visible")
    rows = [{n: stimulus.get(n) for n in names}]
    for tick in range(ticks):
        t, t_next = seconds * tick / ticks, seconds * (tick + 1) / ticks
        stimulus.do_step(t, t_next - t)
        rows.append({n: stimulus.get(n) for n in names})
    return {n: np.array([row[n] for row in rows]) for n in rows[0]}


def observed_delays(out, period=2.0):
    """Every tactile event's delay after its visual event, read from the outputs when it first appears."""
    tactile = out["tactile_time"]
    fresh = np.isfinite(tactile[1:]) & (tactile[1:] != tactile[:-1])
    times = tactile[1:][fresh]
    return times - np.floor(times / period) * period


@pytest.mark.parametrize("low, high, wrong_high", [(0.0, 0.1, 1.0), (0.0, 1.0, 0.1)])
def test_sync_and_async_delays_follow_their_uniform_distributions(low, high, wrong_high):
    out = run_stimulus(30.0, 60, delay_min=low, delay_max=high, seed=np.arange(60))
    delays = observed_delays(out)
    assert len(delays) >= 60 * 14  # 15 visual events in 30 s; the last tactile may fall after the end
    assert stats.kstest(delays, "uniform", args=(low, high - low)).pvalue > 0.01
    assert stats.kstest(delays, "uniform", args=(0.0, wrong_high)).pvalue < 1e-6  # the test can tell them apart


def test_visual_events_every_two_seconds_to_the_step_and_tactile_on_the_first_step_after():
    out = run_stimulus(30.0, 3, delay_min=0.0, delay_max=1.0, seed=[1, 2, 3])
    visual = out["visual_time"][:, 0]
    changes = np.flatnonzero(visual[1:] != visual[:-1]) + 1
    assert list(changes) == list(range(100, 1501, 100))  # ticks 100, 200, ...: t = 2, 4, ..., 30 s
    assert list(visual[changes]) == [2.0 * k for k in range(1, 16)]
    assert np.all(np.isneginf(out["visual_time"][:100])) and np.all(np.isneginf(out["tactile_time"][:100]))
    tactile = out["tactile_time"]
    for trial in range(3):
        column = tactile[:, trial]
        for tick in np.flatnonzero(column[1:] != column[:-1]) + 1:
            event = column[tick]
            assert tick * STEP >= event - 1e-9 > (tick - 1) * STEP  # the first step at or after it


def test_fixed_delay_and_seeding():
    fixed = observed_delays(run_stimulus(10.0, 2, delay_min=0.3, delay_max=0.3))
    assert np.allclose(fixed, 0.3, atol=1e-12) and len(fixed) == 2 * 4  # the 5th falls at 10.3 s
    first = run_stimulus(10.0, 3, delay_max=1.0, seed=[5, 5, 6])
    again = run_stimulus(10.0, 3, delay_max=1.0, seed=[5, 5, 6])
    assert np.array_equal(first["tactile_time"], again["tactile_time"])
    assert np.array_equal(first["tactile_time"][:, 0], first["tactile_time"][:, 1])  # same seed, same trial
    assert not np.array_equal(first["tactile_time"][:, 0], first["tactile_time"][:, 2])
    generator = np.random.default_rng(6)  # the per-trial Generator, drawn event by event
    expected = 2.0 * np.arange(1, 5) + generator.uniform(0.0, 1.0, 4)
    assert np.allclose(np.unique(first["tactile_time"][:, 2][np.isfinite(first["tactile_time"][:, 2])]), expected)


def test_ball_reaches_the_target_at_each_visual_event_and_moves_linearly():
    target = np.array([[-0.45, 0.5], [-0.15, 0.5]])
    out = run_stimulus(4.0, 2, target=target, ball_distance=0.2)
    ball = out["ball"]
    for tick in (100, 200):  # t = 2 s, 4 s
        assert np.allclose(ball[tick], target, atol=1e-12)
    assert np.allclose(ball[0], target + [0.0, 0.2])  # t = 0: a full period from the first event
    assert np.allclose(ball[50], target + [0.0, 0.1])  # t = 1 s: half way
    assert np.allclose(ball[101], target + [0.0, 0.2 * 0.99])  # just after an event it starts again
    assert np.allclose(np.diff(ball[1:100, :, 1], axis=0), -0.2 * STEP / 2.0)


@pytest.mark.parametrize("parameters, name", [({"delay_min": -0.1}, "delay_min"),
                                              ({"delay_min": 0.5, "delay_max": 0.2}, "delay_max"),
                                              ({"period": 0.0}, "period"), ({"seed": 1.5}, "seed")])
def test_bad_parameters_are_one_error_naming_them(parameters, name):
    with pytest.raises(ComponentError, match=f"stimulus.{name}"):
        run_stimulus(0.1, 1, **parameters)
