"""Ecos, the third master (master/export/ssp_ecos.py): an exported system package run unchanged by Ecos gives
libcosim's trajectory, with the package's parameter set applied, and what the machine lacks is named in one line.

Truth: libcosim's run of the same package (tests/test_ssp_export.py holds libcosim against the native master),
and the stimulus's own geometry (the ball rides on the rubber hand, ``offset_x`` from the real one).

The tolerance is 0 (bitwise), derived: both masters are fixed-step Jacobi masters that pass the outputs after
initialization to the inputs before the first step, and the FMUs are deterministic functions of their
parameters, inputs and communication points. The communication points are the one thing the masters compute
differently - libcosim from integer nanoseconds, Ecos by adding the step to the time - so the package's step
here is 2^-6 s (15625000 ns), for which both are exact: the same points, hence the same bits. At the
experiment's 0.02 s, which binary cannot hold, Ecos's sums drift from libcosim's by an ulp of the time, and the
outputs that depend on the time (the ball, the action) by a few ulps (measured: 4.4e-16 at most over 25 steps,
docs/fmi.md).
"""
import concurrent.futures
import importlib.util
import os

import numpy as np
import pytest

from rhi.components.body import kinematics
from rhi.master.cosim import ConfigError
from rhi.master.export import ssp_ecos
from rhi.master.export.body import export_body
from rhi.master.export.ssp_package import build_ssp
from rhi.master.export.system import run_ssp
from tests.in_process import rhi_in_process
from tests.test_agent import agent_fmu, quick  # noqa: F401 (fixtures)

ECOS = ssp_ecos.missing() is None  # ecospy, and on Linux the TBB library it links to (make setup installs both)
needs_ecos = pytest.mark.skipif(not ECOS, reason=str(ssp_ecos.missing()))
LIBCOSIM = importlib.util.find_spec("libcosimpy") is not None
STEP, STEPS = 2.0 ** -6, 8  # a step binary holds exactly (see above); 8 steps: a touch and the ball's return
OTHER = "conv_right_async_0"  # a trial the package holds but does not bind (it binds conv_left_sync_0)


@pytest.fixture(scope="module")
def dyadic(agent_fmu, quick, tmp_path_factory):  # noqa: F811
    """The agent and the C body as an exported system package, its step 2^-6 s, a touch every 0.0625 s."""
    folder = tmp_path_factory.mktemp("ecos")
    config = {**quick, "experiment": {**quick["experiment"], "steps": STEPS, "step_size": STEP},
              "stimulus": {**quick["stimulus"], "period": 4 * STEP}}
    return build_ssp(folder / "RHI.ssp", str(agent_fmu), str(export_body(folder / "Body.fmu", "kinematic-c")),
                     config, "conv")


@needs_ecos
def test_ecos_gives_libcosims_trajectory_bitwise_with_the_parameter_set_applied(dyadic):
    if not LIBCOSIM:
        pytest.skip("libcosimpy is not installed (the test extra)")
    with concurrent.futures.ThreadPoolExecutor(2) as pool:  # each master in a child process of its own
        runs = {master: pool.submit(run_ssp, dyadic, master, OTHER, timeout=120) for master in ("ecos", "libcosim")}
        ecos, libcosim = (runs[master].result() for master in ("ecos", "libcosim"))
    assert sorted(ecos) == sorted(libcosim) and len(ecos["time"]) == STEPS
    assert np.array_equal(ecos["time"], STEP * np.arange(1, STEPS + 1))
    for name in ecos:  # every connector: an input as each step was given it, an output after the step
        assert np.array_equal(ecos[name], libcosim[name]), name
    # The trial's parameters applied, in place of the bound trial's (offset_x -0.15 m, delays up to 0.1 s): the
    # ball rides on the rubber hand, offset_x = 0.15 m right of the resting hand; 1e-15: a few roundings of
    # positions under 1 m (ulp 1.1e-16) between the resting pose and the hand.
    assert np.allclose(ecos["agent.ball_x"], kinematics.REST_HAND[0] + 0.15, rtol=0, atol=1e-15)
    # Ecos applying the bound set itself (by its name, sim.init(parameter_set=...)): tests/test_ssp_values.py,
    # where the bound file's proprioceptive_variance = 0 makes the agent refuse to start under every master.


@needs_ecos
def test_what_the_machine_lacks_for_ecos_is_named_in_one_line(dyadic, tmp_path, monkeypatch):
    from rhi.master.export import ssp_ecos

    monkeypatch.setattr(ssp_ecos, "TBB", "libtbb-not-here.so.99")
    done = rhi_in_process(["run-system", str(dyadic), "--master", "ecos", "--out", str(tmp_path / "o.csv")],
                          os.getcwd(), {})
    assert done.status == 2 and done.stderr.strip() == (
        "rhi run-system: error: --master ecos needs libtbb-not-here.so.99, which ecospy's library links to "
        "(Debian: apt-get install libtbb12)"), done.stderr
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "ecospy" else spec(name, *a))
    with pytest.raises(ConfigError, match=r"^--master ecos needs ecospy \(pip install ecospy==0\.7\.2"):
        run_ssp(dyadic, "ecos")
    assert not (tmp_path / "o.csv").exists()


spec = importlib.util.find_spec
