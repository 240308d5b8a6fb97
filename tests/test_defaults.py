"""One source of truth: every parameter of every component of the experiment is tied to defaults.toml.

The table is master/config/sources.py PARAMETER_SOURCES (the task's TASK_SOURCES and the paper model's BRAIN_SOURCES); these tests check that it covers the
components' parameters exactly, that each plain key's TOML value is the component's declared start
value (same type), that parameters() passes exactly the configured value, and that the [train] and
fast-mode defaults are the training and fast-decoder code's own.
"""
import ast
import dataclasses
import inspect
import re

import numpy as np
import pytest

from rhi.components.body import camera, kinematics
from rhi.components.body.camera import Camera
from rhi.components.stimulus import block_rows
from rhi.components.vision.component import Decoder, GenerativeModel
from rhi.components.vision.fast import DEFAULT_TOLERANCE, LinearisedDecoder
from rhi.components.vision.networks import build
from rhi.components.vision.training import TrainSettings
from rhi.master import config as configuration
from rhi.master.config import protocol
from rhi.master.config import sources
from rhi.master.tasks.illusion import wiring

RESOLUTION = 16
SOURCES = sources.PARAMETER_SOURCES
PLAIN = sorted(path for path, source in SOURCES.items() if sources.config_key(source))
DERIVED = sorted(path for path, source in SOURCES.items() if source.startswith("derived:"))


@pytest.fixture(scope="module")
def systems(tmp_path_factory):
    """The real experiment system around a tiny untrained decoder: exact and fast (linearised)."""
    config = configuration.load(overrides={"experiment.resolution": RESOLUTION})
    model = GenerativeModel(build("conv", "tiny", RESOLUTION).decoder, kinematics.REST_POSE, (40.0, 50.0))
    return {"exact": wiring.build_system(Decoder(model, threads=1), config),
            "fast": wiring.build_system(LinearisedDecoder(model, threads=1, fast_layout=False), config)}


@pytest.fixture(scope="module")
def declared(systems):
    """component.parameter -> its Variable, over both systems."""
    found = {}
    for system in systems.values():
        for name, component in system.components.items():
            for variable in component.variables.values():
                if variable.causality == "parameter":
                    found[f"{name}.{variable.name}"] = variable
    return found


def toml_value(key: str):
    """The shipped defaults.toml value at ``table.key`` (KeyError naming it if absent)."""
    table, name = key.split(".")
    shipped = configuration.defaults()
    if table not in shipped or name not in shipped[table]:
        raise KeyError(f"defaults.toml has no key {key}")
    return shipped[table][name]


def same(a, b) -> bool:
    """Equal and of the same type (1 is not 1.0, True is not 1)."""
    return type(a) is type(b) and a == b


def test_every_component_parameter_has_exactly_one_source(systems, declared):
    for kind, system in systems.items():
        missing = [f"{name}.{v.name}" for name, component in system.components.items()
                   for v in component.variables.values()
                   if v.causality == "parameter" and f"{name}.{v.name}" not in SOURCES]
        assert not missing, f"{kind} system: parameters without an entry in sources.PARAMETER_SOURCES: {missing}"
    stale = sorted(set(SOURCES) - set(declared))
    assert not stale, f"sources.PARAMETER_SOURCES names parameters no component declares: {stale}"
    # A dict literal keeps the last of two equal keys silently: read the tables' sources for duplicates.
    from rhi.master.models import paper
    keys = []
    for module, name in ((sources, "TASK_SOURCES"), (paper, "BRAIN_SOURCES")):
        tree = ast.parse(inspect.getsource(module))
        table = next(node.value for node in ast.walk(tree) if isinstance(node, ast.Assign)
                     and any(getattr(target, "id", None) == name for target in node.targets))
        keys += [key.value for key in table.keys]
    assert len(keys) == len(set(keys)), f"the sources repeat {sorted({k for k in keys if keys.count(k) > 1})}"


def test_every_source_is_handled_one_way():
    """Plain keys are passed as configured; the rest are per trial, derived or given to a constructor."""
    for path, source in SOURCES.items():
        ways = [name for name, holds in (("plain", bool(sources.config_key(source))), ("per trial", path in sources.PER_TRIAL),
                                         ("derived", path in sources.DERIVED), ("constructed", path in sources.CONSTRUCTED))
                if holds]
        assert len(ways) == 1, f"{path}: source {source!r} is handled {ways or 'no way'}"
        assert source.startswith("derived:") == (path in sources.DERIVED), \
            f"{path}: only a 'derived:' source may have (and must have) a value in sources.DERIVED"


@pytest.mark.parametrize("path", PLAIN)
def test_toml_value_is_the_start_value_and_is_passed_as_is(path, declared):
    key = sources.config_key(SOURCES[path])
    value, start = toml_value(key), declared[path].start
    assert same(value, start), (f"defaults.toml {key} = {value!r} ({type(value).__name__}) but the component's "
                                f"{path} starts at {start!r} ({type(start).__name__})")
    config = configuration.load(overrides={"experiment.resolution": RESOLUTION})
    given = wiring.parameters(protocol.plan(config)[:2], config)[path]
    assert same(given, value), f"parameters() passes {path} = {given!r}, but defaults.toml {key} = {value!r}"


def test_a_configured_value_reaches_its_parameter():
    """Not only the defaults: a changed key is what parameters() passes."""
    changed = {"brain.action_limit": 2.5, "body.servo_gain": 30.0, "body.substeps": 40, "body.held": False,
               "camera.blur": 0.02, "camera.ball_radius": 0.05, "stimulus.ball_distance": 0.3}
    config = configuration.load(overrides=changed)
    given = wiring.parameters(protocol.plan(config)[:1], config)
    for key, value in changed.items():
        path = next(p for p, source in SOURCES.items() if source == key)
        assert same(given[path], value), f"{key} = {value!r} configured, parameters() passes {given[path]!r}"


def test_per_trial_sources_take_the_trial_s_entry():
    config = configuration.load(overrides={"experiment.trials": 2})
    trials = protocol.plan(config)
    given = wiring.parameters(trials, config)
    for path, field in sources.PER_TRIAL.items():
        key = SOURCES[path].split()[0]
        for index, trial in enumerate(trials):
            if key == "experiment.seed":
                expected = protocol.trial_seed(config["experiment"]["seed"], trial.condition, trial.stimulation,
                                               trial.index)
            else:
                cursor = config
                for part in key.replace("<condition>", trial.condition).replace(
                        "<stimulation>", trial.stimulation).split("."):
                    cursor = cursor[part]
                expected = cursor
            if path == "stimulus.blocks":  # laid out for the component: one block over the trial when []
                assert np.array_equal(given[path][index], block_rows(expected), equal_nan=True)
                continue
            if path == "stimulus.hidden":  # no hidden time by default: one unused (NaN) row
                assert expected == [] and np.isnan(given[path][index]).all() and given[path][index].shape == (1, 2)
                continue
            if path in ("camera.arm_visible", "stimulus.arm_in_view"):  # the arm is in view unless the trial's condition is hidden
                expected = trial.condition not in expected
            assert given[path][index] == expected, f"{path} of trial {trial}: {given[path][index]!r} != {key} " \
                                                   f"= {expected!r}"
    assert given["stimulus.seed"].dtype == np.int64


def test_constructed_sources_name_a_key_whose_default_is_the_constructor_s(systems):
    for path in sources.CONSTRUCTED:
        key = SOURCES[path].split()[0]
        assert re.fullmatch(r"[a-z_]+\.[a-z_]+", key), f"{path}: {SOURCES[path]!r} does not start with its key"
        toml_value(key)
    resolution = systems["exact"].components["camera"].variables["resolution"].start
    assert resolution == RESOLUTION  # build_system gives the configured resolution to the camera
    default_camera = Camera().variables["resolution"].start
    assert same(toml_value("experiment.resolution"), default_camera), \
        f"defaults.toml experiment.resolution = {toml_value('experiment.resolution')!r}, Camera() has {default_camera!r}"
    tolerance = systems["fast"].components["decoder"].variables["relinearise_tolerance"].start
    assert same(toml_value("decoder.relinearise_tolerance"), tolerance), \
        f"defaults.toml decoder.relinearise_tolerance = {toml_value('decoder.relinearise_tolerance')!r}, " \
        f"LinearisedDecoder starts at {tolerance!r}"


def test_relinearise_tolerance_is_the_fast_decoder_s_default():
    value = toml_value("decoder.relinearise_tolerance")
    assert same(value, DEFAULT_TOLERANCE), \
        f"defaults.toml decoder.relinearise_tolerance = {value!r}, rhi.components.vision.fast.DEFAULT_TOLERANCE = " \
        f"{DEFAULT_TOLERANCE!r}"


@pytest.mark.parametrize("path", DERIVED)
def test_derived_sources_give_their_reason_and_value(path):
    reason = SOURCES[path].partition("derived:")[2].strip()
    assert reason, f"{path}: a derived source must say why it is not a configuration key"
    config = configuration.load()
    given = wiring.parameters(protocol.plan(config)[:1], config)[path]
    assert np.array_equal(given, sources.DERIVED[path]())


def test_derived_values():
    config = configuration.load()
    given = wiring.parameters(protocol.plan(config)[:1], config)
    assert given["brain.mu0"].tolist() == list(kinematics.REST_POSE)
    assert (given["body.q0_shoulder"], given["body.q0_elbow"]) == kinematics.REST_POSE
    assert given["rubber_arm.offset_y"] == 0.0


def test_component_tables_hold_only_parameters():
    """Every key of a component's table in defaults.toml sets a parameter (no dead keys), but the
    decoder's choice of checkpoint and mode, which pick the component rather than set it."""
    used = {source.split()[0] for source in SOURCES.values() if not source.startswith("derived:")}
    choices = {"decoder.conv_checkpoint", "decoder.vae_checkpoint", "decoder.fast"}
    shipped = configuration.defaults()
    for table in ("brain", "body", "stimulus", "camera", "decoder"):
        for key in shipped[table]:
            assert f"{table}.{key}" in used | choices, f"defaults.toml {table}.{key} sets no component parameter"


def test_train_table_is_the_training_code_s_defaults():
    shipped = configuration.defaults()["train"]
    fields = {field.name: field.default for field in dataclasses.fields(TrainSettings)}
    for key, value in shipped.items():
        assert key in fields, f"defaults.toml train.{key} is not a TrainSettings field"
        assert same(value, fields[key]), (f"defaults.toml train.{key} = {value!r}, TrainSettings.{key} defaults to "
                                          f"{fields[key]!r}")
    missing = sorted(set(fields) - set(shipped) - {"resolution"})  # resolution is experiment.resolution
    assert not missing, f"TrainSettings fields without a [train] key in defaults.toml: {missing}"
    assert "resolution" not in shipped


def test_camera_table_is_the_camera_s_constants():
    assert same(toml_value("camera.blur"), camera.BLUR_SIGMA)
    assert same(toml_value("camera.ball_radius"), camera.BALL_RADIUS)
