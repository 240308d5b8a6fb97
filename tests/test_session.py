"""rhi.master.cosim.Session: the one loop, stepped by hand, is simulate's run; the outside world's inputs.

Truth: ``simulate`` (the same system, parameters and ticks; bitwise), and the exact solution of an
integrator under a zero-order-hold input.
"""
import numpy as np
import pytest

from rhi.master.cosim import ConfigError, Session, SimulationError, System, simulate, tick_times
from tests.toys import Constant, FirstOrder


def chain():
    return System([Constant("source"), FirstOrder("plant"), FirstOrder("lagged")],
                  [("source.y", "plant.u"), ("plant.x", "lagged.u")])


@pytest.mark.parametrize("scheme", ["gauss-seidel", "jacobi"])
def test_a_session_stepped_by_hand_is_simulate(scheme):
    parameters = {"source.value": [1.0, -2.0], "plant.rate": 0.5, "lagged.rate": [0.1, 3.0]}
    whole = simulate(chain(), 1.0, 0.1, scheme=scheme, batch_size=2, parameters=parameters,
                     record=["plant.x", "lagged.x"])
    ticks = tick_times(0.0, 1.0, 10).tolist()
    with Session(chain(), 0.0, 1.0, scheme, 2, parameters, ["plant.x", "lagged.x"]) as session:
        for t, end in zip(ticks, ticks[1:]):
            session.step(end - t, start=t)
        by_hand = session.result(tick_times(0.0, 1.0, 10))
        assert session.steps == 10 and session.time == pytest.approx(1.0, abs=1e-15)
    for path in ("plant.x", "lagged.x"):
        assert np.array_equal(by_hand.values[path], whole.values[path])  # bitwise: one loop
    assert np.array_equal(by_hand.times, whole.times)


def test_an_unconnected_input_is_set_from_outside_between_steps():
    # An integrator (rate 0, gain 1) of a zero-order-hold input: x(t) = sum of u_k * h.
    system = System([FirstOrder("plant")], [])
    inputs = [0.5, -1.0, 2.0, 0.25]
    with Session(system, record=["plant.x"]) as session:
        for u in inputs:
            session.set("plant.u", u)
            session.step(0.1)
        assert session.get("plant.x")[0] == pytest.approx(0.1 * sum(inputs), abs=1e-15)
        assert session.result().times == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.4], abs=1e-15)


def test_only_the_outside_worlds_inputs_can_be_set():
    with Session(chain()) as session:
        with pytest.raises(ConfigError, match="plant.u is fed by a connection"):
            session.set("plant.u", 1.0)
        with pytest.raises(ConfigError, match="plant.x is an output"):
            session.set("plant.x", 1.0)
        with pytest.raises(ConfigError, match="no component named 'nobody'"):
            session.set("nobody.u", 1.0)


def test_a_closed_session_does_not_step_and_a_failed_initialization_terminates_everything():
    session = Session(chain())
    session.close()
    with pytest.raises(ConfigError, match="closed"):
        session.step(0.1)
    system = chain()
    with pytest.raises(ConfigError, match="not a parameter"):
        Session(system, parameters={"plant.x": 1.0})
    bad = System([Constant("source"), FirstOrder("plant")], [("source.y", "plant.u")])
    bad.components["plant"].initialize = lambda: (_ for _ in ()).throw(RuntimeError("broken"))
    with pytest.raises(RuntimeError, match="broken"):
        Session(bad)
    assert all(c.state == "terminated" for c in bad.components.values())


def test_a_failed_step_names_the_component_and_the_time():
    system = System([Constant("source"), FirstOrder("plant")], [("source.y", "plant.u")])
    from rhi.components.component import StepFailure

    def fail(t, h):
        raise StepFailure("no more")

    with Session(system) as session:
        session.step(0.1)
        system.components["plant"].step = fail
        with pytest.raises(SimulationError, match=r"plant failed the step at t = 0.1 s \(error\): no more"):
            session.step(0.1)
