"""The agent as one component and as an FMI 2.0 FMU (master/export/agent.py, agent_fmu.py, agent_slave.py).

Truth: the experiment's own system (``wiring.run_batch``: the same trials, seeds and decoder), bitwise;
the components' declared variables and ``defaults.toml`` for every port; fmpy's FMI 2.0 validation.
"""
import json
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.validation import validate_fmu

from rhi.components.body.plant import ArmPlant
from rhi.components.body.contract import BODY_CONTRACT
from rhi.components.fmu import extracted, guard_library
from rhi.master.cosim import System, simulate
from rhi.master.cosim.loop import tick_times
from rhi.master import config as configuration
from rhi.master.config import sources
from rhi.master.tasks.illusion import wiring
from rhi.master.decoders.cache import decoder_component
from rhi.master.config.protocol import make_trial, plan
from rhi.master.export.agent import (OBSERVED, SEED, Agent, agent_connections, exposed, join_seed, parameter_paths,
                                 split_seed)
from rhi.master.export.agent_fmu import MANIFEST, agent_from_resources, build_agent_fmu
from tests.in_process import rhi_in_process

STEPS = 30
LINKS = ("q_shoulder", "q_elbow", "hand_x", "hand_y")  # what the body feeds the agent


@pytest.fixture(scope="session")
def quick(quick_cache):
    """The --quick configuration with the session's tiny conv decoder named as its checkpoint."""
    checkpoint = str(next(Path(quick_cache).glob("conv-*.pt")))
    config = configuration.load(quick=True, overrides={"decoder.conv_checkpoint": checkpoint})
    config["experiment"]["decoders"] = ["conv"]
    return config


@pytest.fixture(scope="session")
def agent_fmu(quick, tmp_path_factory):
    return build_agent_fmu(tmp_path_factory.mktemp("agent") / "Agent.fmu", "conv", quick,
                           quick["decoder"]["conv_checkpoint"])


def with_steps(config, steps, period=0.2):
    """``config`` for a short run: ``steps`` steps, and a touch every ``period`` s (2 s in the experiment), so
    that gamma, the event times and the belief all move within it."""
    return {**config, "experiment": {**config["experiment"], "steps": steps},
            "stimulus": {**config["stimulus"], "period": period}}


def agent_parameters(trials, name="agent"):
    """The per-trial parameters of the agent, as the experiment gives them to the inner components."""
    low, high = zip(*(split_seed(t.seed) for t in trials))
    return {f"{name}.offset_x": [t.offset_x for t in trials], f"{name}.delay_min": [t.delay_min for t in trials],
            f"{name}.delay_max": [t.delay_max for t in trials], f"{name}.seed": np.array(low),
            f"{name}.seed_high": np.array(high)}


def test_a_seed_of_63_bits_goes_through_two_fmi_integers():
    seeds = [0, 1, 2 ** 31 - 1, 2 ** 31, 2 ** 32 - 1, 2 ** 32, 2 ** 63 - 1] + [t.seed for t in plan(configuration.load())]
    for seed in seeds:
        low, high = split_seed(seed)
        assert -2 ** 31 <= low < 2 ** 31 and 0 <= high < 2 ** 31  # each fits an fmi2Integer
        assert int(join_seed(low, high)) == seed
    assert split_seed(42) == (42, 0)  # a small seed is itself
    with pytest.raises(ValueError, match="outside"):
        split_seed(2 ** 63)


def test_every_port_is_declared_by_a_component_and_every_start_is_the_configuration(quick):
    agent = Agent(quick["decoder"]["conv_checkpoint"], "conv", quick)
    inner = wiring.build_system(decoder_component("conv", quick["decoder"]["conv_checkpoint"], quick), quick)
    contract = {c.name: c for c in BODY_CONTRACT}
    for name in LINKS[:2] + ("hand_x", "hand_y"):  # inputs: the body contract's outputs, as the brain declares them
        port, brain = agent.variables[name], inner.variable(f"brain.{name}")
        assert (port.causality, port.unit, port.description) == ("input", brain.unit, brain.description)
        assert contract[name].causality == "output" and contract[name].unit == port.unit
    for name in ("u_shoulder", "u_elbow"):  # the action: the body contract's inputs
        assert agent.variables[name].causality == "output" and contract[name].causality == "input"
        assert agent.variables[name].unit == contract[name].unit == inner.variable(f"brain.{name}").unit
    for name, path, _ in OBSERVED:
        assert agent.variables[name].unit == inner.variable(path).unit
        assert agent.variables[name].description.startswith(inner.variable(path).description)
    # Every parameter the experiment sets on the five components is an agent parameter, or is fixed by design.
    paths = [p for p in sources.PARAMETER_SOURCES if not p.startswith("body.")]
    assert {p for p in paths if exposed(p, quick)} == set(parameter_paths(inner, quick))
    for path in parameter_paths(inner, quick):
        name, variable = path.partition(".")[2], inner.variable(path)
        if path == SEED:
            assert agent.variables["seed"].type == agent.variables["seed_high"].type == "Integer"
            continue
        port = agent.variables[name]
        assert (port.unit, port.min, port.max, port.type) == (variable.unit, variable.min, variable.max, variable.type)
        key = sources.config_key(sources.PARAMETER_SOURCES[path])
        table, _, entry = (key or "").partition(".")
        assert port.start == (quick[table][entry] if key else variable.start), path  # defaults.toml, one truth
    assert sorted(agent_connections()) == sorted(
        (s.replace("brain.", "agent."), t.replace("brain.", "agent.")) for s, t in wiring.CONNECTIONS if "body." in s + t)


def test_the_agent_with_a_body_is_the_experiment_bitwise(quick):
    config = with_steps(quick, STEPS)
    trials = [make_trial(config, "conv", "left", "sync", 0), make_trial(config, "conv", "right", "async", 1)]
    native = wiring.run_batch(decoder_component("conv", config["decoder"]["conv_checkpoint"], config), trials, config)
    agent = Agent(config["decoder"]["conv_checkpoint"], "conv", quick)  # built at 2 s; the period is a parameter
    body = {p: v for p, v in wiring.parameters(trials, config).items() if p.startswith("body.")}
    result = simulate(System([agent, ArmPlant()], agent_connections()), STEPS * 0.02, 0.02, batch_size=2,
                      parameters={**agent_parameters(trials), **body, "agent.period": 0.2},
                      record=["agent.mu_shoulder", "agent.mu_elbow", "agent.gamma", "agent.u_shoulder",
                              "agent.visual_time", "agent.tactile_time", "body.force_x", "body.q_shoulder"])
    pairs = {"agent.mu_shoulder": native.values["brain.mu"][..., 0], "agent.mu_elbow": native.values["brain.mu"][..., 1],
             "agent.gamma": native.values["brain.gamma"], "agent.u_shoulder": native.values["brain.u_shoulder"],
             "agent.visual_time": native.values["stimulus.visual_time"],
             "agent.tactile_time": native.values["stimulus.tactile_time"],
             "body.force_x": native.values["body.force_x"], "body.q_shoulder": native.values["body.q_shoulder"]}
    for path, expected in pairs.items():
        assert np.array_equal(result.values[path], expected), path
    assert np.isfinite(result.values["agent.tactile_time"][-1, 0])  # touches happened (sync): the test can fail
    assert result.values["agent.gamma"][-1, 0] > 0.05  # the sync trial infers a common cause


def test_the_agent_fmu_is_valid_and_declares_the_agent(agent_fmu, quick):
    assert validate_fmu(str(agent_fmu)) == []
    agent = Agent(quick["decoder"]["conv_checkpoint"], "conv", quick)
    description = read_model_description(str(agent_fmu))
    assert [v.name for v in description.modelVariables] == list(agent.variables)
    for fmi in description.modelVariables:
        mine = agent.variables[fmi.name]
        assert (fmi.causality, fmi.type, fmi.unit or "") == (mine.causality, mine.type, mine.unit if mine.type == "Real" else "")
        if mine.causality in ("parameter", "input"):
            start = float(fmi.start)
            assert start == mine.start or (np.isnan(start) and np.isnan(mine.start)), fmi.name
    names = zipfile.ZipFile(agent_fmu).namelist()
    assert {"resources/decoder.pt", f"resources/{MANIFEST}"} <= set(names)


def open_fmu(fmu_path, callbacks=None, logging=False):
    """An FMU instance under fmpy's FMU2Slave (``callbacks``: fmpy's default logger, or one's own), its value
    references by name, and its model description."""
    description = read_model_description(str(fmu_path))
    unzipped = extracted(str(fmu_path))
    guard_library(unzipped, description.coSimulation.modelIdentifier)
    saved = list(sys.path)
    fmu = FMU2Slave(guid=description.guid, unzipDirectory=unzipped,
                    modelIdentifier=description.coSimulation.modelIdentifier, instanceName="agent")
    fmu.instantiate(callbacks=callbacks, loggingOn=logging)
    sys.path[:] = saved  # a pythonfmu FMU prepends its resources to sys.path
    return fmu, {v.name: v.valueReference for v in description.modelVariables}, description


def drive_by_hand(fmu_path, steps, reals=(), integers=(), body=()):
    """The agent FMU under fmpy's FMU2Slave, the body a native ArmPlant, stepped by hand in the experiment's
    order (agent, then body with the new action) at this master's communication points (``simulate``'s tick
    grid, whose steps differ from 0.02 s in the last bit): every output of the agent per step, and the body's hand
    (``body.hand_x``, ``body.hand_y``). ``reals``, ``integers``: the FMU's parameters ``{name: value}``;
    ``body``: the ArmPlant's ``{variable: value}``."""
    fmu, ref, description = open_fmu(fmu_path)
    plant = ArmPlant()
    plant.instantiate(1)
    for name, value in dict(body).items():
        plant.set(name, value)
    fmu.setupExperiment(startTime=0.0)
    for setter, values in ((fmu.setReal, dict(reals)), (fmu.setInteger, dict(integers))):
        if values:
            setter([ref[n] for n in values], list(values.values()))
    plant.setup_experiment(0.0, None)
    plant.enter_initialization_mode()
    fmu.enterInitializationMode()
    inputs = [v.name for v in description.modelVariables if v.causality == "input"]
    feed = lambda: fmu.setReal([ref[n] for n in inputs], [float(plant.values[n][0]) for n in inputs])
    act = lambda: [plant.set(n, np.array(fmu.getReal([ref[n]]))) for n in ("u_shoulder", "u_elbow")]
    feed()
    fmu.exitInitializationMode()
    act()
    plant.exit_initialization_mode()
    outputs = [v.name for v in description.modelVariables if v.causality == "output"]
    rows = []
    ticks = tick_times(0.0, steps * 0.02, steps).tolist()  # this master's communication points
    for tick in range(steps):
        t, h = ticks[tick], ticks[tick + 1] - ticks[tick]
        feed()
        fmu.doStep(t, h)
        act()
        plant.do_step(t, h)
        rows.append(fmu.getReal([ref[n] for n in outputs]) + [plant.values[n][0] for n in ("hand_x", "hand_y")])
    fmu.terminate()
    fmu.freeInstance()
    return dict(zip(outputs + ["body.hand_x", "body.hand_y"], np.array(rows).T))


def test_the_agent_fmu_stepped_by_fmpy_by_hand_is_the_native_trial(agent_fmu, quick):
    config = with_steps(quick, STEPS)
    trial = make_trial(config, "conv", "left", "sync", 0)
    native = wiring.run_batch(decoder_component("conv", config["decoder"]["conv_checkpoint"], config), [trial], config)
    low, high = split_seed(trial.seed)
    body = {p[5:]: v for p, v in wiring.parameters([trial], config).items() if p.startswith("body.")}
    by_hand = drive_by_hand(agent_fmu, STEPS, reals={"offset_x": trial.offset_x, "delay_min": trial.delay_min,
                                                     "delay_max": trial.delay_max,
                                                     "period": config["stimulus"]["period"]},
                            integers={"seed": low, "seed_high": high}, body=body)
    expected = {"mu_shoulder": native.values["brain.mu"][1:, 0, 0], "mu_elbow": native.values["brain.mu"][1:, 0, 1],
                "gamma": native.values["brain.gamma"][1:, 0], "u_elbow": native.values["brain.u_elbow"][1:, 0],
                "free_energy": native.values["brain.free_energy"][1:, 0],
                "ball_y": native.values["stimulus.ball"][1:, 0, 1]}
    for name, values in expected.items():  # measured: bitwise (the same code, batch size and order)
        np.testing.assert_allclose(by_hand[name], values, rtol=0, atol=1e-12, err_msg=name)
    assert np.ptp(by_hand["mu_shoulder"]) > 1e-3  # the belief moved: equality is not of constants


def test_an_agent_fmu_of_another_rhi_is_refused(agent_fmu, tmp_path):
    with zipfile.ZipFile(agent_fmu) as archive:
        archive.extractall(tmp_path)
    manifest = json.loads((tmp_path / "resources" / MANIFEST).read_text())
    manifest["ports"] = manifest["ports"][1:] + [["flux", "output", "Real", "1"]]
    (tmp_path / "resources" / MANIFEST).write_text(json.dumps(manifest))
    with pytest.raises(RuntimeError, match="another version of rhi.*flux, offset_x"):
        agent_from_resources(str(tmp_path / "resources"))


def rhi(*args):
    return subprocess.run([sys.executable, "-m", "rhi", *args], capture_output=True, text=True, timeout=600)


def test_rhi_export_agent_writes_a_valid_fmu_and_refuses_in_one_line(quick, tmp_path):
    checkpoint = quick["decoder"]["conv_checkpoint"]
    done = rhi("export-agent", "--quick", "--decoder", "conv", "--checkpoint", checkpoint, "--out", str(tmp_path / "A.fmu"))
    assert done.returncode == 0, done.stderr[-2000:]
    assert validate_fmu(str(tmp_path / "A.fmu")) == []
    (tmp_path / "folder.fmu").mkdir()
    refusals = {
        ("--decoder", "vae", "--checkpoint", checkpoint, "--out", str(tmp_path / "B.fmu")): "a conv decoder, given as the vae",
        ("--checkpoint", checkpoint, "--out", str(tmp_path / "C.fmu")): "--checkpoint needs --decoder",
        ("--decoder", "conv", "--checkpoint", checkpoint, "--out", str(tmp_path / "folder.fmu")): "is a folder",
        ("--decoder", "conv", "--checkpoint", checkpoint, "--out", str(tmp_path / "D.txt")): "must be a file name ending in .fmu",
        ("--decoder", "mlp", "--out", str(tmp_path / "E.fmu")): "not one of conv, vae",
    }
    for args, message in refusals.items():  # main() in this process (tests/in_process.py), as a fresh one runs it
        done = rhi_in_process(["export-agent", "--quick", *args], Path.cwd(), {})
        lines = done.stderr.strip().splitlines()
        assert done.status == 2 and len(lines) == 1 and message in lines[0], (args, done.stderr)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["A.fmu", "folder.fmu"]  # nothing half-written


def check_port_table(name, agent):
    """docs/fmi.md's generated table ``name`` of an agent FMU's ports, row by row, against ``agent``'s declarations."""
    import math

    from docs_tables import block

    rows = [line for line in block("fmi.md", name).splitlines() if line.startswith("| ")][1:]  # no header

    def number(v, kind):
        return {"−∞": -math.inf, "∞": math.inf}[v] if v in ("−∞", "∞") else (int(v) if kind == "Integer" else float(v))

    assert [row.split("|")[1].strip().strip("`") for row in rows] == list(agent.variables)
    for row in rows:
        port, causality, kind, unit, bounds, start, meaning = (cell.strip() for cell in row.split("|")[1:-1])
        variable = agent.variables[port.strip("`")]
        assert (causality, kind, unit, meaning) == (variable.causality, variable.type, variable.unit or "1",
                                                    variable.description), port
        low, high = (number(v.strip(), kind) for v in bounds.strip("[]").split(","))
        assert low == (-math.inf if variable.min is None else variable.min), port
        assert high == (math.inf if variable.max is None else variable.max), port
        if variable.causality == "output":
            assert start == ""
        else:
            value = {"NaN": math.nan, "∞": math.inf}.get(start) if start in ("NaN", "∞") else float(start)
            close = value == variable.start or math.isclose(value, variable.start, rel_tol=5e-6)  # %g: 6 digits
            assert close or (math.isnan(value) and math.isnan(variable.start)), port


def test_the_documented_table_of_ports_is_the_agents_declarations(quick):
    """docs/fmi.md's generated table of the agent FMU's ports, row by row, against the agent's declared variables."""
    check_port_table("agent-ports", Agent(quick["decoder"]["conv_checkpoint"], "conv", quick))


# The illusion agent FMU's ports (name, causality, type, unit) as they were before the reach agent: an FMU built
# by an earlier rhi keeps working, and a master wired to them too.
ILLUSION_PORTS = (
    [[name, "parameter", "Real", unit] for name, unit in (("offset_x", "m"), ("offset_y", "m"), ("period", "s"),
                                                          ("delay_min", "s"), ("delay_max", "s"))]
    + [["seed", "parameter", "Integer", "1"], ["seed_high", "parameter", "Integer", "1"]]
    + [[name, "parameter", "Real", unit] for name, unit in (
        ("ball_distance", "m"), ("stop_time", "s"), ("ball_radius", "m"), ("visual_variance", "1"),
        ("proprioceptive_variance", "deg2"), ("gamma0", "1"), ("sync_sd", "s"), ("async_density", "1/s"),
        ("decay_rate", "1/s3"), ("action_limit", "deg/s"), ("spatial_sd", "m"), ("action_time_constant", "s"))]
    + [[name, "input", "Real", unit] for name, unit in (("hand_x", "m"), ("hand_y", "m"), ("q_shoulder", "deg"),
                                                        ("q_elbow", "deg"))]
    + [[name, "output", "Real", unit] for name, unit in (
        ("u_shoulder", "deg/s"), ("u_elbow", "deg/s"), ("mu_shoulder", "deg"), ("mu_elbow", "deg"), ("gamma", "1"),
        ("free_energy", "1"), ("action_rate_shoulder", "deg/s2"), ("action_rate_elbow", "deg/s2"),
        ("visual_time", "s"), ("tactile_time", "s"), ("visual_error", "1"), ("ball_x", "m"), ("ball_y", "m"),
        ("perceived_hand_x", "m"), ("perceived_hand_y", "m"))])


def test_the_illusion_agent_keeps_its_ports_and_its_connections(agent_fmu, quick):
    from rhi.master.export.agent_fmu import ports

    agent = Agent(quick["decoder"]["conv_checkpoint"], "conv", quick)
    assert ports(agent) == ILLUSION_PORTS
    assert agent.connections() == agent_connections() == [
        ("body.hand_x", "agent.hand_x"), ("body.hand_y", "agent.hand_y"), ("body.q_shoulder", "agent.q_shoulder"),
        ("body.q_elbow", "agent.q_elbow"), ("agent.u_shoulder", "body.u_shoulder"), ("agent.u_elbow", "body.u_elbow")]
    with zipfile.ZipFile(agent_fmu) as archive:
        manifest = json.loads(archive.read(f"resources/{MANIFEST}"))
    assert manifest["task"] == "illusion" and manifest["ports"] == ILLUSION_PORTS
    assert read_model_description(str(agent_fmu)).coSimulation.modelIdentifier == "RubberHandAgent"


def test_an_agent_without_a_body_or_with_a_bad_delay_law_fails_naming_why(quick):
    from rhi.components.component import ComponentError
    from rhi.master.cosim import SimulationError

    checkpoint = quick["decoder"]["conv_checkpoint"]
    with pytest.raises(SimulationError, match=r"agent failed the step at t = 0 s .*q_shoulder is not finite \(nan\)"):
        simulate(System([Agent(checkpoint, "conv", quick)], []), 0.02, 0.02)
    with pytest.raises(ComponentError, match=r"stimulus.delay_max = \[0.1\] is below delay_min = \[0.5\]"):
        simulate(System([Agent(checkpoint, "conv", quick)], []), 0.02, 0.02, parameters={"agent.delay_min": 0.5})
