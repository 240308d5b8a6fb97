"""The reach agent as one component, as an FMI 2.0 FMU and in an SSP package (master/export/reach_agent.py, tasks.py).

Truth: `rhi reach`'s own system (``reach.run_reaches``: the same goals and decoder), bitwise; the reach system's
links and defaults (docs/reach.md); ``reach.goal_problem``'s rule; for the SSP package under FMPy, an
independent master written here that does what FMPy's SSP loop does; for libcosim, this master's Jacobi run.
"""
import concurrent.futures
import importlib.util
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from rhi.components.body import kinematics
from rhi.components.body.contract import BODY_CONTRACT
from rhi.components.body.plant import ArmPlant
from rhi.components.component import ComponentError
from rhi.master.commands.cli import main
from rhi.master.cosim import System, simulate
from rhi.master.tasks.reach import task as reach
from rhi.master.config import sources
from rhi.master.export.agent_fmu import MANIFEST, agent_from_resources
from rhi.master.export.body import build_fmu
from rhi.master.export.reach_agent import ReachAgent
from rhi.master.export.ssp_check import read_ssp, trial_parameters
from rhi.master.export.ssp_package import build_ssp
from rhi.master.export.system import final_goal_distance_cm, run_ssp
from tests.test_agent import check_port_table, drive_by_hand, open_fmu

STEPS, H = 30, 0.02
STEP_NS = 20_000_000  # libcosim's step: its time is an integer of nanoseconds
LIBCOSIM = importlib.util.find_spec("libcosimpy") is not None
# The agent's and the body's ports compared, and where `rhi reach`'s system has each: (path, element).
RECORD = {"agent.mu_shoulder": ("brain.mu", 0), "agent.mu_elbow": ("brain.mu", 1),
          "agent.u_shoulder": ("brain.u_shoulder",), "agent.u_elbow": ("brain.u_elbow",),
          "agent.free_energy": ("brain.free_energy",), "agent.goal_error": ("goal_decoder.visual_error",),
          "agent.goal_hand_x": ("goal.hand", 0), "agent.goal_hand_y": ("goal.hand", 1),
          "body.hand_x": ("body.hand_x",), "body.hand_y": ("body.hand_y",)}


@pytest.fixture(scope="module")
def config(quick_cache):
    """``rhi reach --quick`` (tiny decoders at 32 px, 2 near goals) with the session's conv decoder, 30 steps."""
    checkpoint = str(next(Path(quick_cache).glob("conv-*.pt")))
    return reach.load(quick=True, overrides={"decoder.conv_checkpoint": checkpoint, "experiment.decoders": ["conv"],
                                             "experiment.steps": STEPS})


@pytest.fixture(scope="module")
def reach_fmu(config, tmp_path_factory):
    """``rhi export-agent --task reach`` in this process."""
    out = tmp_path_factory.mktemp("reach") / "Reach.fmu"
    assert main(["export-agent", "--task", "reach", "--quick", "--decoder", "conv", "--checkpoint",
                 config["decoder"]["conv_checkpoint"], "--out", str(out)]) == 0
    return out


def native(config, trials):
    """``rhi reach``'s lockstep run of ``trials``: ``{agent or body path: (steps + 1, B)}`` as RECORD names them."""
    values = reach.run_reaches("conv", config["decoder"]["conv_checkpoint"], trials, config,
                             extra=["goal_decoder.visual_error"]).values
    return {port: values[path][..., element[0]] if element else values[path]
            for port, (path, *element) in RECORD.items()}


def body_parameters(config, prefix="body."):
    return {prefix + path[5:]: value for path, value in sources.shared_parameters(config, ("body",)).items()}


def goals(trials, prefix="agent."):
    return {f"{prefix}goal_shoulder": np.array([t.goal_pose[0] for t in trials]),
            f"{prefix}goal_elbow": np.array([t.goal_pose[1] for t in trials])}


def test_the_reach_agent_declares_the_reach_and_with_a_free_body_is_rhi_reach_bitwise(config):
    agent = ReachAgent(config["decoder"]["conv_checkpoint"], "conv", config)
    # The reach system's body links (docs/reach.md): the sensed joints in, the action out; nothing else.
    assert agent.connections() == [("body.q_shoulder", "agent.q_shoulder"), ("body.q_elbow", "agent.q_elbow"),
                                   ("agent.u_shoulder", "body.u_shoulder"), ("agent.u_elbow", "body.u_elbow")]
    contract = {c.name: c for c in BODY_CONTRACT}
    for name in ("q_shoulder", "q_elbow", "u_shoulder", "u_elbow"):
        assert agent.variables[name].unit == contract[name].unit
    first = reach.plan(config)[0]
    starts = {n: v.start for n, v in agent.variables.items() if v.causality == "parameter"}
    assert (starts.pop("goal_shoulder"), starts.pop("goal_elbow")) == first.goal_pose  # the plan's first goal
    assert starts.pop("precision_ratio") == config["reach"]["precision_ratio"] == 2.0
    assert starts.pop("visual_variance") == config["decoder"]["visual_variance"]
    assert starts == {k: config["brain"][k] for k in starts}  # the brain's, from defaults.toml and reach.toml
    assert starts["action_time_constant"] == np.inf  # reach.toml's: the released agent's action law

    trials = reach.plan(config)[:2]
    expected = native(config, trials)
    result = simulate(System([agent, ArmPlant()], agent.connections()), STEPS * H, H, batch_size=2,
                      parameters={**goals(trials), **body_parameters(config)}, record=list(RECORD))
    for path, values in expected.items():
        assert np.array_equal(result.values[path], values, equal_nan=True), path  # NaN: free energy before a step
    moved = np.hypot(*(result.values[f"body.hand_{a}"][-1] - result.values[f"body.hand_{a}"][0] for a in "xy"))
    assert np.all(moved > 1e-4)  # the free arm moved: more than the held arm's 0.1 mm on its load cell
    assert not np.array_equal(*result.values["agent.goal_hand_x"][0])  # two goals, each its own


def test_a_goal_outside_the_joint_ranges_is_refused_in_one_line(config, reach_fmu, capsys):
    checkpoint = config["decoder"]["conv_checkpoint"]
    far = kinematics.REST_POSE[0] + 45.0  # shoulder rest ± 40 deg is what the decoders know
    message = (f"goal_shoulder = {far:g} deg is 45 deg from rest ({kinematics.REST_POSE[0]:g} deg): it leaves the "
               "joint ranges the decoders know (shoulder rest ± 40 deg, elbow rest ± 50 deg)")
    assert reach.goal_problem(far, kinematics.REST_POSE[1]) == message
    assert reach.goal_problem(kinematics.REST_POSE[0] + 39.9, kinematics.REST_POSE[1] - 49.9) is None
    assert "goal_elbow = nan" in reach.goal_problem(kinematics.REST_POSE[0], np.nan)
    with pytest.raises(ComponentError) as error:  # this master: the initialization fails, before any step
        simulate(System([ReachAgent(checkpoint, "conv", config)], []), H, H, parameters={"agent.goal_shoulder": far})
    assert str(error.value) == f"agent: {message}"
    capsys.readouterr()
    assert fails_to_initialize(reach_fmu, {"goal_shoulder": far})  # the FMU: its initialization fails, saying why
    assert [line for line in capsys.readouterr().out.splitlines() if line.startswith("[ERROR]")] == [
        f"[ERROR] agent: {message}"]


def fails_to_initialize(fmu_path, reals):
    """Whether the FMU's initialization fails with the parameters ``reals``; its log goes to stdout (fmpy's
    logger prints each message as ``[STATUS] message``). A failed instance is left as it is: pythonfmu reports
    the failure as fmi2Fatal, after which FMI 2.0 allows no call (its fmi2FreeInstance may crash)."""
    from fmpy.fmi1 import FMICallException

    fmu, ref, _ = open_fmu(fmu_path, logging=True)
    fmu.setupExperiment(startTime=0.0)
    fmu.setReal([ref[name] for name in reals], list(reals.values()))
    fmu.enterInitializationMode()
    try:
        fmu.exitInitializationMode()
    except FMICallException:
        return True
    fmu.terminate()
    fmu.freeInstance()
    return False


def test_the_reach_agent_fmu_under_fmpy_by_hand_is_rhi_reach(config, reach_fmu):
    assert validate_fmu(str(reach_fmu)) == []
    description = read_model_description(str(reach_fmu))
    agent = ReachAgent(config["decoder"]["conv_checkpoint"], "conv", config)
    assert [v.name for v in description.modelVariables] == list(agent.variables)
    assert description.coSimulation.modelIdentifier == "ReachAgent"
    with zipfile.ZipFile(reach_fmu) as archive:
        assert json.loads(archive.read(f"resources/{MANIFEST}"))["task"] == "reach"
    trial = reach.plan(config)[1]
    expected = native(config, [trial])
    by_hand = drive_by_hand(reach_fmu, STEPS, reals={k.partition(".")[2]: v[0] for k, v in goals([trial]).items()},
                            body=body_parameters(config, prefix=""))
    for path, values in expected.items():  # measured: bitwise (the same code, batch size and order)
        name = path if path.startswith("body.") else path.partition(".")[2]
        assert np.array_equal(by_hand[name], values[1:, 0]), path


def test_the_documented_table_of_the_reach_agents_ports_is_its_declarations(config):
    check_port_table("reach-agent-ports", ReachAgent(config["decoder"]["conv_checkpoint"], "conv", config))


def test_reach_exports_refuse_what_they_cannot_carry_in_one_line(tmp_path, capsys):
    (tmp_path / "body.toml").write_text('[reach]\nattractor = "body"\n')
    refusals = {
        ("export-agent", "--task", "reach", "--config", str(tmp_path / "body.toml"), "--out", str(tmp_path / "A.fmu")):
            "reach.attractor = 'body' reads the goal with a pose encoder, which the agent FMU does not carry",
        ("export-agent", "--task", "walk", "--out", str(tmp_path / "B.fmu")):
            "--task 'walk' is not one of illusion, reach",
        ("export-system", "--task", "reach", "--quick", "--trial", "far/0", "--out", str(tmp_path / "R.ssp")):
            "--trial 'far/0': no band 'far' (have: near)",
        ("export-system", "--task", "reach", "--quick", "--trial", "near/2", "--out", str(tmp_path / "R.ssp")):
            "--trial 'near/2': no goal 2 (reach.goals = 2)",
    }
    for args, expected in refusals.items():
        assert main(list(args)) == 2
        lines = capsys.readouterr().err.splitlines()
        assert len(lines) == 1 and expected in lines[0], (args, lines)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["body.toml"]


def jacobi_loop(agent, body, parameters, steps, master):
    """What the SSP masters do, on native components, written here from their sources: each component is
    instantiated, given its parameters and initialized; each step every component reads its inputs, steps on
    them (Jacobi), and its outputs are copied to the inputs they feed. ``master`` = "fmpy"
    (fmpy.ssp.simulation.simulate_ssp): no input is set at initialization, every connector starts at 0, the
    time is the sum of the steps; "libcosim": the inputs start at the outputs after initialization, the time
    is an integer of nanoseconds (:data:`STEP_NS` a step) divided by 1e9, and the step the difference of two
    such times (measured: a step of exactly 0.02 s differs from libcosim's in the last bit of the action)."""
    links = agent.connections()
    components = {"agent": agent, "body": body}
    for name, component in components.items():
        component.instantiate(1)
        for path, value in parameters.items():
            if path.startswith(name + "."):
                component.set(path.partition(".")[2], value)
        component.setup_experiment(0.0, None)
        component.enter_initialization_mode()

    def outputs():
        return {target: float(components[source.split(".")[0]].values[source.split(".")[1]][0])
                for source, target in links}

    for component in components.values():
        component.exit_initialization_mode()
    connectors = {target: 0.0 for _, target in links} if master == "fmpy" else outputs()
    rows, t = {path: [] for path in RECORD}, 0.0
    for tick in range(steps):
        if master == "fmpy":
            start, h = t, H
        else:  # libcosim: the step is the difference of the two times in seconds
            start, h = tick * STEP_NS / 1e9, (tick + 1) * STEP_NS / 1e9 - tick * STEP_NS / 1e9
        for name, component in components.items():
            for target, value in connectors.items():
                if target.startswith(name + "."):
                    component.set(target.partition(".")[2], value)
            assert component.do_step(start, h) == 0, component.last_reason
        connectors, t = outputs(), t + H
        for path in rows:
            rows[path].append(float(components[path.split(".")[0]].values[path.split(".")[1]][0]))
    return {path: np.array(values) for path, values in rows.items()}


def test_the_reach_as_an_ssp_package_runs_free_under_fmpy_and_libcosim(config, reach_fmu, tmp_path):
    body_fmu = build_fmu(tmp_path / "Body.fmu", "native")
    package = build_ssp(tmp_path / "Reach.ssp", str(reach_fmu), str(body_fmu), config, "conv", task="reach")
    checked = read_ssp(package)
    plan = reach.plan(config)
    assert sorted(p for p in checked.parameters if "trials/" in p) == sorted(
        f"resources/trials/conv_near_{t.index}.ssv" for t in plan)
    assert checked.connections == [tuple(s.split(".") + t.split(".")) for s, t in ReachAgent(
        config["decoder"]["conv_checkpoint"], "conv", config).connections()]
    for trial in plan:
        values = trial_parameters(checked, f"conv_near_{trial.index}")
        assert (values["agent"]["goal_shoulder"][1], values["agent"]["goal_elbow"][1]) == trial.goal_pose
        assert values["body"]["held"] == ("Boolean", False)
    checkpoint = config["decoder"]["conv_checkpoint"]
    with concurrent.futures.ThreadPoolExecutor(2) as pool:  # the masters run in child processes meanwhile
        runs = {"fmpy": pool.submit(run_ssp, package, "fmpy", "conv_near_1", STEPS, timeout=600)}
        if LIBCOSIM:
            runs["libcosim"] = pool.submit(run_ssp, package, "libcosim", None, STEPS, timeout=600)
        expected = {master: jacobi_loop(ReachAgent(checkpoint, "conv", config), ArmPlant(),
                                        {**goals(plan[index:index + 1]), **body_parameters(config)}, STEPS, master)
                    for master, index in (("fmpy", 1), ("libcosim", 0))[:len(runs)]}
        results = {master: run.result() for master, run in runs.items()}
    for master, values in expected.items():
        for path in RECORD:  # measured: bitwise (the same code and order of operations)
            assert np.array_equal(results[master][path], values[path]), (master, path)
        moved = np.hypot(values["body.hand_x"][-1] - values["body.hand_x"][0],
                         values["body.hand_y"][-1] - values["body.hand_y"][0])
        assert moved > 1e-4, master  # free: the master gave the body held = false
    goal = kinematics.forward(*plan[1].goal_pose)  # what run-system prints: the final distance to the goal, cm
    assert final_goal_distance_cm(results["fmpy"]) == pytest.approx(100 * np.hypot(
        expected["fmpy"]["body.hand_x"][-1] - goal[0], expected["fmpy"]["body.hand_y"][-1] - goal[1]), rel=1e-12)
    if not LIBCOSIM:
        pytest.skip("libcosimpy is not installed (the test extra: pip install libcosimpy==0.0.6): only FMPy ran")
