"""Where every component parameter's value comes from, and the values for a batch of trials.

:data:`TASK_SOURCES` says it for the task's components and each model's ``parameter_sources`` for its brain
(:mod:`rhi.master.models`); :func:`parameters` follows both, and tests/test_defaults.py checks that they cover
every component parameter and that each plain key of ``defaults.toml`` equals the component's start value.
:func:`check_parameters` sets them on the components before any work, so a value out of a component's range
is refused naming its key.
"""
from __future__ import annotations

import numpy as np

from rhi.components.body import kinematics
from rhi.components.body.camera import Camera
from rhi.components.body.plant import ArmPlant
from rhi.components.body.rubber_arm import RubberArm
from rhi.components.component import ComponentError
from rhi.components.stimulus import Stimulus, block_rows, interval_rows
from rhi.master import models
from rhi.master.config import population
from rhi.master.config.protocol import HALF_RANGES, Trial, per_trial, plan, table_rows
from rhi.master.cosim import ConfigError, System
from rhi.master.models.base import TrialValues, config_key
from rhi.master.models.paper import BRAIN_SOURCES

# component.parameter -> where its value comes from, for the task's components (the model's brain declares its
# own: rhi.master.models.Model.parameter_sources). A source is one of:
#   "table.key"                  a key of defaults.toml (or the user's config), passed as is by parameters();
#   "table.<name>... (per trial)" the trial's own value, from the [conditions]/[stimulations] entry it runs;
#   "table.key (... )"           the key, used otherwise (hashed per trial, or given to the constructor);
#   "derived: reason"            not a configuration key: parameters() passes the value DERIVED gives.
TASK_SOURCES = {
    "rubber_arm.offset_x": "conditions.<condition> (per trial: the trial's condition)",
    "rubber_arm.offset_y": "rubber_arm.offset_y",
    "stimulus.period": "stimulus.period",
    "stimulus.delay_min": "stimulations.<stimulation>.delay_min (per trial: the trial's stimulation)",
    "stimulus.delay_max": "stimulations.<stimulation>.delay_max (per trial: the trial's stimulation)",
    "stimulus.seed": "experiment.seed (hashed per trial: protocol.trial_seed of seed, condition, stimulation, "
                     "index)",
    "stimulus.ball_distance": "stimulus.ball_distance",
    "stimulus.stop_time": "stimulus.stop_time",
    "stimulus.stroke_duration": "stimulus.stroke_duration",
    "stimulus.touch": "stimulations.<stimulation>.touch (per trial: the trial's stimulation)",
    "stimulus.blocks": "stimulations.<stimulation>.blocks (per trial: the trial's stimulation, as "
                       "rhi.components.stimulus.block_rows lays them out)",
    "stimulus.hidden": "rubber_arm.hidden_times (per trial: with the readings when readings.hide_arm, as "
                       "rhi.master.config.schedules.hidden_intervals merges them)",
    "stimulus.arm_in_view": "rubber_arm.hidden_conditions (per trial: false where the trial's condition is listed)",
    "camera.arm_visible": "rubber_arm.hidden_conditions (per trial: false where the trial's condition is listed)",
    "camera.resolution": "experiment.resolution (structural: build_system gives it to Camera(resolution=...))",
    "camera.blur": "camera.blur",
    "camera.ball_radius": "camera.ball_radius",
    "decoder.visual_variance": "decoder.visual_variance",
    "decoder.relinearise_tolerance": "decoder.relinearise_tolerance (fast mode only: decoders.decoder_component "
                                     "gives it to LinearisedDecoder(relinearise_tolerance=...))",
    "body.held": "body.held",
    "body.q0_shoulder": "derived: the rest pose's shoulder, rhi.components.body.kinematics.REST_POSE[0]; the real arm "
                        "starts at rest (docs/design.md fixes the geometry; the decoders are trained around it)",
    "body.q0_elbow": "derived: the rest pose's elbow, rhi.components.body.kinematics.REST_POSE[1]; the real arm "
                     "starts at rest (docs/design.md fixes the geometry; the decoders are trained around it)",
    "body.substeps": "body.substeps",
    "body.servo_gain": "body.servo_gain",
    "body.torque_limit": "body.torque_limit",
    "body.upper_arm_mass": "body.upper_arm_mass",
    "body.forearm_mass": "body.forearm_mass",
    "body.clamp_stiffness": "body.clamp_stiffness",
    "body.clamp_damping": "body.clamp_damping",
    "body.release_time": "body.release_time",
}
# The paper's whole system: the task's components and the paper model's brain.
PARAMETER_SOURCES = {**TASK_SOURCES, **BRAIN_SOURCES}

def sources(config: dict) -> dict:
    """Every component parameter's source under ``config``: the task's (:data:`TASK_SOURCES`) and its model's brain's
    (``Model.parameter_sources``); for the paper's model, :data:`PARAMETER_SOURCES`."""
    return {**TASK_SOURCES, **models.of(config).parameter_sources}


# The values of the "derived:" sources, and the trial field of the per-trial ones.
DERIVED = {
    "brain.mu0": lambda: np.array(kinematics.REST_POSE, dtype=float),
    "body.q0_shoulder": lambda: kinematics.REST_POSE[0],
    "body.q0_elbow": lambda: kinematics.REST_POSE[1],
}
PER_TRIAL = {"rubber_arm.offset_x": "offset_x", "stimulus.delay_min": "delay_min",
             "stimulus.delay_max": "delay_max", "stimulus.seed": "seed", "stimulus.touch": "touch",
             "stimulus.blocks": "blocks", "stimulus.hidden": "hidden", "stimulus.arm_in_view": "arm_visible",
             "camera.arm_visible": "arm_visible"}
# How a per-trial field becomes its parameter's value, where it is not the field as it is.
# (the tables laid out with as many rows as the protocol's fullest, :func:`rhi.master.config.protocol.table_rows`)
PER_TRIAL_VALUE = {"stimulus.seed": lambda values, rows: np.array(values).astype(np.int64),
                   "stimulus.blocks": lambda values, rows: np.stack([block_rows(blocks, rows[0]) for blocks in values]),
                   "stimulus.hidden": lambda values, rows: np.stack([interval_rows(hidden, rows[1]) for hidden in values])}
CONSTRUCTED = ("camera.resolution", "decoder.relinearise_tolerance")  # given to the constructors instead


def parameters(trials: list[Trial], config: dict) -> dict:
    """Per-trial and shared parameters, as ``component.variable`` paths: the task's components' as TASK_SOURCES
    says (but the CONSTRUCTED ones, fixed when the components are built), then the model's brain's."""
    given, rows = {}, table_rows(config, trials)
    for path, source in TASK_SOURCES.items():
        if path in CONSTRUCTED:
            continue
        if path in PER_TRIAL:
            values = [getattr(t, PER_TRIAL[path]) for t in trials]
            given[path] = PER_TRIAL_VALUE.get(path, lambda values, rows: np.array(values))(values, rows)
        elif path in DERIVED:
            given[path] = DERIVED[path]()
        else:
            given[path] = per_trial(trials, config, config_key(source))
    return {**given, **model_parameters(config, [t.seed for t in trials], lambda key: per_trial(trials, config, key))}


def shared_parameters(config: dict, names) -> dict:
    """The parameters of the task's components ``names`` that are the same for every trial, as TASK_SOURCES
    says: the derived ones and the plain configuration keys, not the per-trial nor the CONSTRUCTED ones."""
    given = {}
    for path, source in TASK_SOURCES.items():
        if path.split(".")[0] in names and path not in CONSTRUCTED and path not in PER_TRIAL:
            if path in DERIVED:
                given[path] = DERIVED[path]()
            else:
                table, name = config_key(source).split(".")
                given[path] = config[table][name]
    return given


def batchable_keys(config: dict) -> set[str]:
    """The configuration keys that may differ between the trials of one lockstep batch: the float keys that
    set a component parameter as they are (TASK_SOURCES and the model's sources), each applied per trial, and
    those a model derives a parameter from (``Model.batchable``). Everything else (structure, sizes,
    checkpoints, the decoder's constructor settings) is the batch's own."""
    model = models.of(config)
    sources = [s for p, s in TASK_SOURCES.items() if p not in CONSTRUCTED]
    sources += [*model.parameter_sources.values(), *model.batchable]
    keys = set()
    for source in sources:
        key = config_key(source)
        if key is not None:
            table, name = key.split(".")
            if isinstance(config.get(table, {}).get(name), float):
                keys.add(key)
    return keys


def undeclared(given: dict, system: System) -> list[str]:
    """The ``body.*`` paths of ``given`` that the system's body does not declare.

    A body swapped in (an FMU, a variant) must meet the body contract (docs/design.md: held, q0_*), not
    carry the native plant's physics: the [body] keys it lacks are left out, and the run records them.
    Any other component's parameter is always declared (tests/test_defaults.py).
    """
    variables = system.components["body"].variables
    return [path for path in given if path.startswith("body.") and path.partition(".")[2] not in variables]


def trial_values(config: dict, seeds, value) -> TrialValues:
    """What a model's parameters are computed from: the configuration, the trials' seeds (B,) and ``value(key)``."""
    return TrialValues(config, np.asarray(seeds, dtype=np.int64), value, tuple(kinematics.REST_POSE),
                       tuple(HALF_RANGES))


def model_parameters(config: dict, seeds, value) -> dict:
    """The model's brain parameters for trials of these ``seeds`` (:meth:`rhi.master.models.Model.parameters`)."""
    return models.of(config).parameters(trial_values(config, seeds, value))


def check_parameters(config: dict) -> None:
    """Before any work: every parameter the configuration gives the components (but the decoder, which
    config.validate checks) within the range the component declares and meeting the component's own rules
    (:meth:`Component.check_parameters`: a positive sd, a rubber hand within reach); a ConfigError naming
    the key."""
    check_reach(config)
    trials = plan(config)
    given = parameters(trials, config)
    try:
        camera = Camera(resolution=config["experiment"]["resolution"])
    except ComponentError as error:
        raise ConfigError(f"experiment.resolution: {error}") from None
    model = models.of(config)
    blocks, hidden = table_rows(config)
    components = {c.name: c for c in (RubberArm(), Stimulus(blocks=blocks, hidden=hidden), camera, model.brain(),
                                      ArmPlant())}
    for component in components.values():
        component.instantiate(len(trials))
    for path, value in given.items():
        name, _, variable = path.partition(".")
        if name not in components or variable not in components[name].variables:
            continue
        try:
            components[name].set(variable, value)
        except ComponentError as error:
            source = {**TASK_SOURCES, **model.parameter_sources}.get(path, path).split()[0]
            raise ConfigError(f"{source}: {error}") from None
    for component in components.values():
        try:
            component.check_parameters()
        except ComponentError as error:
            raise ConfigError(str(error)) from None


def check_population(config: dict) -> None:
    """The ``[population]`` table against the configuration: each key one that may differ between the trials of a
    batch (:func:`batchable_keys`), its median and bounds, and its draws within the range its component declares
    (:func:`rhi.master.config.population.check_entry`); a ConfigError naming the entry."""
    import difflib

    allowed = sorted(batchable_keys(config))
    for key, entry in population.entries(config).items():
        if key not in allowed:
            close = difflib.get_close_matches(key, allowed, n=1)
            hint = f"did you mean {close[0]}? " if close else ""
            raise ConfigError(f"population.{key} is not a parameter of the {models.of(config).name} model that can "
                              f"differ between participants ({hint}one of {', '.join(allowed)})")
        population.check_entry(key, entry, config, declared_range(config, key))


def check_reach(config: dict) -> None:
    """Each condition's rubber hand within the arm's reach (RubberArm.check_parameters), named by condition."""
    for name in config["experiment"]["conditions"]:
        arm = RubberArm()
        arm.instantiate(1)
        try:
            arm.set("offset_x", config["conditions"][name])
            arm.set("offset_y", config["rubber_arm"]["offset_y"])
            arm.check_parameters()
        except ComponentError as error:
            raise ConfigError(f"conditions.{name} = {config['conditions'][name]} m (rubber_arm.offset_y = "
                              f"{config['rubber_arm']['offset_y']} m) puts the rubber hand out of the arm's reach: "
                              f"{str(error).partition(': ')[2]}") from None


def declared_range(config: dict, key: str) -> tuple[str, float | None, float | None, str] | None:
    """The component parameter that configuration ``key`` sets as it is (TASK_SOURCES and the model's sources) and
    the range its component declares: (``component.variable``, min, max, unit), None for a key that sets none."""
    model = models.of(config)
    for path, source in {**TASK_SOURCES, **model.parameter_sources}.items():
        if config_key(source) != key:
            continue
        name, _, variable = path.partition(".")
        if name == "decoder":  # built around a trained network: its one parameter's range, without one
            from rhi.components.vision.component import MIN_VISUAL_VARIANCE

            return (path, MIN_VISUAL_VARIANCE, None, "1") if variable == "visual_variance" else None
        makers = {"rubber_arm": RubberArm, "stimulus": Stimulus, "body": ArmPlant, "brain": model.brain,
                  "camera": lambda: Camera(resolution=config["experiment"]["resolution"])}
        if name not in makers:
            return None
        declared = makers[name]().variables.get(variable)
        if declared is not None:
            return path, declared.min, declared.max, declared.unit
    return None
