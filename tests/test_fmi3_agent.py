"""The agent as an FMI 3.0 FMU (pythonfmu3, master/export/agent_fmi3.py): valid under two checkers, the FMI 2.0
agent's numbers to the last bit under FMPy, and the camera's image as a Float64 array output.

Truth: the FMI 2.0 agent FMU (tests/test_agent.py holds it against the native trial), and for the image, which
the FMI 2.0 agent does not show, the native agent component (rhi.master.export.agent.Agent) stepped alike.
"""
import importlib.util
import sys

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi3 import FMU3Slave

from rhi.components.body.plant import ArmPlant
from rhi.components.fmu import extracted, guard_library
from rhi.master.config.protocol import make_trial
from rhi.master.cosim import ConfigError
from rhi.master.export.agent import Agent, split_seed
from rhi.master.export.agent_fmu import build_agent_fmu, check_fmi
from rhi.master.export.fmi_checks import CHECKS
from tests.test_agent import agent_fmu, quick, with_steps  # noqa: F401 (fixtures)

pytestmark = pytest.mark.skipif(importlib.util.find_spec("pythonfmu3") is None,
                                reason="pythonfmu3 is not installed (the test extra: pip install pythonfmu3==0.3.4)")
STEPS, PERIOD = 12, 0.06  # touches within the run: the event times, gamma and the belief all move


@pytest.fixture(scope="module")
def agent3(quick, tmp_path_factory):  # noqa: F811
    return build_agent_fmu(tmp_path_factory.mktemp("agent3") / "Agent3.fmu", "conv", quick,
                           quick["decoder"]["conv_checkpoint"], fmi="3.0")


def parameters(config):
    trial = make_trial(config, "conv", "left", "sync", 0)
    low, high = split_seed(trial.seed)
    return {"offset_x": trial.offset_x, "delay_min": trial.delay_min, "delay_max": trial.delay_max,
            "period": PERIOD}, {"seed": low, "seed_high": high}


class Native:
    """The native agent component behind the calls the drive below makes of an FMU."""

    def __init__(self, config):
        self.agent = Agent(config["decoder"]["conv_checkpoint"], "conv", config)
        self.agent.instantiate(1)

    def set(self, values):
        for name, value in values.items():
            if self.agent.variables[name].causality == "parameter":
                self.agent.set(name, np.array([value]))
            else:
                self.agent.values[name] = np.array([float(value)])


def drive(path, config, steps=STEPS):
    """The agent (an FMU under FMPy's FMU2Slave or FMU3Slave, or ``Native``) with a native pymunk body, stepped by
    hand, agent first: its scalar outputs per step, and its image per step (FMI 3.0 and native)."""
    reals, integers = parameters(config)
    plant = ArmPlant()
    plant.instantiate(1)
    plant.setup_experiment(0.0, None)
    plant.enter_initialization_mode()
    if path is None:
        native = Native(config)
        agent = native.agent
        outputs = [v.name for v in agent.variables.values() if v.causality == "output"]
        inputs = [v.name for v in agent.variables.values() if v.causality == "input"]
        native.set({**reals, **integers})
        agent.setup_experiment(0.0, None)
        agent.enter_initialization_mode()
        feed = lambda: native.set({n: plant.values[n][0] for n in inputs})
        get = lambda names: [float(agent.values[n][0]) for n in names]
        image = lambda: np.asarray(agent.inner("camera.image")[0], dtype=np.float64).ravel()
        exit_init, step, close = agent.exit_initialization_mode, agent.do_step, agent.terminate
    else:
        description = read_model_description(str(path))
        fmi3 = description.fmiVersion == "3.0"
        unzipped = extracted(str(path))
        if not fmi3:  # pythonfmu 0.7's library, released at exit (components/fmu/library.py)
            guard_library(unzipped, description.coSimulation.modelIdentifier)
        saved = list(sys.path)
        fmu = (FMU3Slave if fmi3 else FMU2Slave)(
            guid=description.guid, unzipDirectory=unzipped, instanceName="agent",
            modelIdentifier=description.coSimulation.modelIdentifier)
        fmu.instantiate()
        sys.path[:] = saved  # a python FMU prepends its resources to sys.path
        ref = {v.name: v.valueReference for v in description.modelVariables}
        variables = [v for v in description.modelVariables if v.name not in ("image", "time")]
        outputs = [v.name for v in variables if v.causality == "output"]
        inputs = [v.name for v in variables if v.causality == "input"]
        set_reals, set_ints = (fmu.setFloat64, fmu.setInt32) if fmi3 else (fmu.setReal, fmu.setInteger)
        set_reals([ref[n] for n in reals], list(reals.values()))
        set_ints([ref[n] for n in integers], list(integers.values()))
        if fmi3:
            fmu.enterInitializationMode(startTime=0.0)
        else:
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
        feed = lambda: set_reals([ref[n] for n in inputs], [float(plant.values[n][0]) for n in inputs])
        get = lambda names: list((fmu.getFloat64 if fmi3 else fmu.getReal)([ref[n] for n in names]))
        size = 32 * 32 if fmi3 else 0
        image = (lambda: np.array(fmu.getFloat64([ref["image"]], nValues=size))) if fmi3 else (lambda: None)
        exit_init, step = fmu.exitInitializationMode, fmu.doStep
        close = lambda: (fmu.terminate(), fmu.freeInstance())
    feed()
    exit_init()
    act = lambda: [plant.set(n, np.array(get([n]))) for n in ("u_shoulder", "u_elbow")]
    act()
    plant.exit_initialization_mode()
    rows, images = [], []
    for k in range(steps):
        t, h = k * 0.02, 0.02
        feed()
        step(t, h)
        act()
        plant.do_step(t, h)
        rows.append(get(outputs))
        images.append(image())
    close()
    return dict(zip(outputs, np.array(rows).T)), images


def test_the_fmi3_agent_passes_both_checkers_and_declares_initial(agent3):
    assert {name: check(agent3) for name, check in CHECKS.items()} == {name: [] for name in CHECKS}
    description = read_model_description(str(agent3))
    variables = {v.name: v for v in description.modelVariables}
    image = variables["image"]
    assert (image.type, image.causality, [d.start for d in image.dimensions]) == ("Float64", "output", [32, 32])
    assert variables["tactile_time"].variability == variables["visual_time"].variability == "discrete"
    assert variables["seed"].type == "Int32" and variables["time"].causality == "independent"


def test_the_fmi3_agent_is_its_fmi2_twin_to_the_last_bit_and_shows_the_native_image(agent3, agent_fmu, quick):  # noqa: F811
    config = with_steps(quick, STEPS, PERIOD)
    three, images = drive(agent3, config)
    two, _ = drive(agent_fmu, config)
    assert sorted(three) == sorted(two)
    for name in two:
        assert np.array_equal(three[name], two[name]), name
    assert np.ptp(three["mu_shoulder"]) > 0 and np.isfinite(three["tactile_time"][-1])  # moved; a touch felt
    native, native_images = drive(None, config)
    assert np.array_equal(native["mu_shoulder"], three["mu_shoulder"])
    for mine, truth in zip(images, native_images):  # the camera's float32 image, widened exactly
        assert np.array_equal(mine, truth)
    assert np.ptp(images[-1]) > 0.1 and not np.array_equal(images[0], images[-1])  # an image, and it changes


def test_fmi3_is_refused_for_the_reach_and_an_unknown_version():
    with pytest.raises(ConfigError, match=r"^--fmi 3\.0 is built for --task illusion only"):
        check_fmi("3.0", "reach")
    with pytest.raises(ConfigError, match=r"^--fmi '1\.0' is not one of 2\.0, 3\.0$"):
        check_fmi("1.0", "illusion")


def test_force_knows_the_fmi3_agent_as_rhi_s_own_and_nothing_else_with_its_layout(agent3, tmp_path):
    """--force replaces an FMU rhi wrote (rhi.master.export.own_files): the FMI 3.0 agent's slave script is
    rhi_agent_slave3_*; the same archive without rhi's agent metadata is not rhi's."""
    import zipfile

    from rhi.master.export.own_files import fmu_problem

    assert fmu_problem(agent3) is None
    stripped = tmp_path / "Other.fmu"
    with zipfile.ZipFile(agent3) as old, zipfile.ZipFile(stripped, "w") as new:
        for item in old.infolist():
            if item.filename != "resources/rhi_agent.json":
                new.writestr(item, old.read(item))
    assert fmu_problem(stripped) == "its model description names another generationTool than rhi and its slave is not rhi's"

