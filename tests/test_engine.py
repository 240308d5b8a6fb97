"""The master: analytic answers, Jacobi vs Gauss-Seidel, validation messages, failures, saving."""

import numpy as np
import pytest
from scipy.linalg import expm

from rhi.components.component import Status
from rhi.master import ConfigError, SimulationError, System, simulate
from rhi.master.cosim.loop import step_count
from tests.toys import Constant, FailsAt, FirstOrder, Gain, Image, ImageSink


def test_constant_into_integrator_is_exact_and_ends_at_30s():
    system = System([Constant(), FirstOrder("integrator")], [("source.y", "integrator.u")])
    result = simulate(system, stop_time=30.0, step_size=0.02, batch_size=2,
                      parameters={"source.value": [1.5, -2.0], "integrator.x0": 0.25},
                      record=["integrator.x"])
    assert len(result.times) == 1501 and result.times[-1] == 30.0  # exactly, on the integer tick counter
    expected = 0.25 + np.array([1.5, -2.0])[None, :] * result.times[:, None]
    np.testing.assert_allclose(result.values["integrator.x"], expected, rtol=1e-12, atol=1e-12)


def coupled(rates=(1.0, 2.0), gains=(0.5, -1.5), x0=(1.0, 0.5)):
    """x1' = -r1 x1 + g1 x2,  x2' = -r2 x2 + g2 x1, as two components feeding each other."""
    first, second = FirstOrder("first"), FirstOrder("second")
    system = System([first, second], [("second.x", "first.u"), ("first.x", "second.u")])
    parameters = {"first.rate": rates[0], "first.gain": gains[0], "first.x0": x0[0],
                  "second.rate": rates[1], "second.gain": gains[1], "second.x0": x0[1]}
    matrix = np.array([[-rates[0], gains[0]], [gains[1], -rates[1]]])
    return system, parameters, matrix, np.array(x0)


@pytest.mark.parametrize("scheme", ["jacobi", "gauss-seidel"])
def test_coupled_error_is_first_order_in_step(scheme):
    system, parameters, matrix, x0 = coupled()
    exact = expm(matrix * 2.0) @ x0
    errors = []
    for h in (0.04, 0.02, 0.01):
        result = simulate(system_copy(), 2.0, h, scheme=scheme, parameters=parameters,
                          record=["first.x", "second.x"])
        final = np.array([result.values["first.x"][-1, 0], result.values["second.x"][-1, 0]])
        errors.append(np.linalg.norm(final - exact))
    ratios = errors[0] / errors[1], errors[1] / errors[2]
    assert all(1.8 < r < 2.2 for r in ratios), (scheme, errors)


def system_copy():
    return coupled()[0]


def test_jacobi_and_gauss_seidel_differ_at_first_order():
    differences = []
    for h in (0.04, 0.02, 0.01):
        finals = []
        for scheme in ("jacobi", "gauss-seidel"):
            system, parameters, _, _ = coupled()
            result = simulate(system, 2.0, h, scheme=scheme, parameters=parameters, record=["first.x"])
            finals.append(result.values["first.x"][-1, 0])
        differences.append(abs(finals[0] - finals[1]))
    assert differences[0] > 0
    assert 1.8 < differences[0] / differences[1] < 2.2 and 1.8 < differences[1] / differences[2] < 2.2


def test_gauss_seidel_reads_new_outputs_and_jacobi_old_ones():
    """One step by hand: an integrator (x0 = 1, u = 0) feeding a gain of 2."""
    for scheme, expected in (("jacobi", 2.0), ("gauss-seidel", 2.0 + 2 * 0.1 * 3.0)):
        system = System([Constant(), FirstOrder("integrator"), Gain()],
                        [("source.y", "integrator.u"), ("integrator.x", "gain.u")])
        result = simulate(system, 0.1, 0.1, scheme=scheme, record=["gain.y"],
                          parameters={"source.value": 3.0, "integrator.x0": 1.0})
        assert result.values["gain.y"][-1, 0] == pytest.approx(expected, abs=1e-12)


# -- validation: every message names what is wrong -------------------------------------------

def expect_config_error(system, pattern, scheme="gauss-seidel"):
    with pytest.raises(ConfigError, match=pattern):
        system.validate(scheme)


def test_unknown_component_and_variable_are_named():
    expect_config_error(System([Constant()], [("sorce.y", "source.value")]),
                        r"connection sorce\.y -> source\.value: sorce\.y: no component named 'sorce'")
    expect_config_error(System([Constant(), FirstOrder()], [("source.why", "plant.u")]),
                        r"connection source\.why -> plant\.u: .*no variable 'why'")


def test_causality_mismatch_is_named():
    expect_config_error(System([Constant(), FirstOrder()], [("plant.u", "source.value")]),
                        r"source plant\.u is an input, not an output.*target source\.value is an parameter")


def test_type_shape_and_unit_mismatch_are_named():
    expect_config_error(System([Constant(), ImageSink()], [("source.y", "decoder.image")]),
                        r"source\.y -> decoder\.image: type mismatch, Real feeds Array\[8, 8\]")
    expect_config_error(System([Image(size=8), ImageSink(size=16)], [("camera.image", "decoder.image")]),
                        r"camera\.image -> decoder\.image: type mismatch, Array\[8, 8\] float32 feeds "
                        r"Array\[16, 16\] float32")
    expect_config_error(System([Constant(unit="m"), FirstOrder(unit="deg")], [("source.y", "plant.u")]),
                        r"source\.y -> plant\.u: unit mismatch, m feeds deg")


def test_unconnected_input_without_start_is_named():
    expect_config_error(System([ImageSink()], []), r"input decoder\.image is not connected and has no start")


def test_input_fed_twice_is_named():
    system = System([Constant("a"), Constant("b"), FirstOrder()], [("a.y", "plant.u"), ("b.y", "plant.u")])
    expect_config_error(system, r"input plant\.u is fed twice: by a\.y and by b\.y")


def test_algebraic_loop_is_named_under_gauss_seidel_only():
    loop = System([Gain("g1"), Gain("g2")], [("g1.y", "g2.u"), ("g2.y", "g1.u")])
    expect_config_error(loop, r"algebraic loop .*: g1\.y -> g2\.u -> g2\.y -> g1\.u -> g1\.y")
    loop.validate("jacobi")  # Jacobi reads last step's outputs: no loop to solve
    # A cycle through a state output is no algebraic loop.
    System([Gain(), FirstOrder()], [("gain.y", "plant.u"), ("plant.x", "gain.u")]).validate()


@pytest.mark.parametrize("start, stop, step, message", [
    (0.0, 1.0, 0.0, "step size must be positive"),
    (0.0, 1.0, -0.02, "step size must be positive"),
    (0.0, 1.01, 0.02, r"stop time 1\.01 is not a whole number of steps of 0\.02"),
    (0.0, 0.0, 0.02, "stop time 0.0 must be after start time"),
    (0.0, float("nan"), 0.02, "stop time must be a finite number"),
    (0.0, 1.0, "0.02", "step size must be a finite number"),
])
def test_bad_step_and_stop_time(start, stop, step, message):
    with pytest.raises(ConfigError, match=message):
        step_count(start, stop, step)


def test_exact_step_counts():
    assert step_count(0.0, 30.0, 0.02) == 1500
    assert step_count(0.0, 0.3, 0.1) == 3  # 0.3 / 0.1 is 2.9999999999999996 in floating point


def test_unknown_parameter_and_record_are_named():
    system = System([Constant()], [])
    with pytest.raises(ConfigError, match=r"source\.valeu: component 'source' has no variable 'valeu'"):
        simulate(system, 1.0, 0.5, parameters={"source.valeu": 2.0})
    with pytest.raises(ConfigError, match=r"source\.y is not a parameter"):
        simulate(System([Constant()], []), 1.0, 0.5, parameters={"source.y": 2.0})


def test_failed_step_names_component_time_and_reason():
    fragile = FailsAt(fail_time=0.5, status=Status.DISCARD)
    with pytest.raises(SimulationError, match=r"fragile failed the step at t = 0\.5 s \(discard\): the toy "
                                              r"was told to fail here"):
        simulate(System([fragile], []), 1.0, 0.1)
    assert fragile.terminated


def test_initialization_keeps_start_value_until_a_later_source_has_output():
    """The gain comes first, so at initialization it sees its start value (0), then the integrator's x."""
    system = System([Gain(), Constant(), FirstOrder("integrator")],
                    [("integrator.x", "gain.u"), ("source.y", "integrator.u")])
    result = simulate(system, 0.2, 0.1, record=["gain.y"], parameters={"integrator.x0": 1.0})
    np.testing.assert_allclose(result.values["gain.y"][:, 0], [0.0, 2.0, 2.2], atol=1e-12)


def test_input_without_start_whose_source_comes_later_is_named():
    system = System([ImageSink(), Image()], [("camera.image", "decoder.image")])
    with pytest.raises(ConfigError, match=r"input decoder\.image has no value at initialization"):
        simulate(system, 0.2, 0.1)


def test_components_step_at_the_integer_tick_times_and_rows_are_copies():
    """t_n = start + (stop - start) * n / N exactly, h = t_(n+1) - t_n; a recorded row is a copy, and a
    path recorded twice is one column."""
    seen = []

    class Clock(Constant):
        def step(self, t, h):
            seen.append((t, h))
            self.values["y"][:] = t + h  # in place (components should not): only copies keep the history

    start, stop, steps = 0.1, 0.4, 3  # 0.1 + 0.3 * n / 3 is not 0.1 + n * 0.1 in floating point
    result = simulate(System([Clock()], []), stop, 0.1, start_time=start, record=["source.y", "source.y"])
    ticks = [start + (stop - start) * n / steps for n in range(steps + 1)]
    assert seen == [(ticks[n], ticks[n + 1] - ticks[n]) for n in range(steps)]
    assert result.times.tolist() == ticks and all(type(t) is float and type(h) is float for t, h in seen)
    assert result.values["source.y"][:, 0].tolist() == [1.0, *ticks[1:]]
