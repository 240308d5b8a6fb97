"""The reach task: its configuration, its goals, its system, and one lockstep batch of it (docs/reach.md).

The free arm (``body.held = false``) starts at rest and reaches to a goal it sees: the camera's image of the
arm at the goal pose (a :class:`~rhi.components.body.arm_pose.PosedArm` in front of a second camera), the released
agent's attractor image. The goal pulls the belief (through the decoder in pixels, or through the pose
encoder in joint angles), the proprioceptive error mu - s_p drives the action, and the arm follows.
"""
from __future__ import annotations

import copy
import hashlib
import tomllib
from dataclasses import dataclass
from importlib import resources

import numpy as np

from rhi.components.body import kinematics
from rhi.components.body.arm_pose import JointPose, PosedArm
from rhi.components.body.camera import Camera
from rhi.components.body.plant import ArmPlant
from rhi.master import models
from rhi.master.cosim import ConfigError, System
from rhi.master import config as configuration
from rhi.master.config import population
from rhi.master.config.protocol import per_trial
from rhi.master.decoders.training_data import HALF_RANGES
from rhi.master.config.sources import model_parameters, shared_parameters
from rhi.master.tasks.scene import Scenario, build, declared, pose_encoders, run

ATTRACTORS = ("auto", "pixels", "body")
VIEWS = ("auto", "on", "off")
RECORD = ["brain.mu", "brain.gamma", "brain.u_shoulder", "brain.u_elbow", "brain.free_energy", "body.q_shoulder",
          "body.q_elbow", "body.hand_x", "body.hand_y"]


@dataclass(frozen=True)
class ReachTrial:
    """One reach: its decoder, band and index, its seed, and the goal's offset from the rest pose (deg)."""

    decoder: str
    band: str
    index: int
    seed: int
    shoulder_offset: float
    elbow_offset: float
    overrides: tuple = ()  # ((key, value), ...): this reach's own parameter values (protocol.Trial.overrides)

    @property
    def goal_pose(self) -> tuple[float, float]:
        """The goal's joint angles (shoulder, elbow) in deg: the rest pose plus this reach's offsets."""
        return kinematics.REST_POSE[0] + self.shoulder_offset, kinematics.REST_POSE[1] + self.elbow_offset


# -- configuration -----------------------------------------------------------------------------------------
def settings_path():
    """The reach's settings file, master/tasks/reach/reach.toml."""
    return resources.files("rhi.master.tasks.reach").joinpath("reach.toml")


def task() -> dict:
    """master/tasks/reach/reach.toml: the task's own table [reach] (and its [quick]), and the keys it changes elsewhere."""
    with settings_path().open("rb") as file:
        return tomllib.load(file)


def load(path=None, quick: bool = False, model_name: str = "paper", overrides: dict | None = None) -> dict:
    """The reach's configuration: the defaults (and their [quick]), the model, master/tasks/reach/reach.toml (and its
    [quick]), the file, the overrides (``{"reach.goals": 2}``); checked, ConfigError naming the key."""
    config = configuration.defaults()
    quick_values = config.pop("quick")
    if quick:
        config = configuration.merge(config, quick_values)
    config = configuration.with_model(config, model_name)
    shipped = task()
    quick_task = shipped.pop("quick")
    config = configuration.merge({**config, "reach": copy.deepcopy(shipped.pop("reach"))}, shipped)
    if quick:
        config = configuration.merge(config, quick_task)
    if path is not None:
        given = configuration.read_toml(path)
        new_bands = given.get("reach", {}).get("ranges", {}) if isinstance(given.get("reach"), dict) else {}
        if isinstance(new_bands, dict):  # a band of one's own: an open table, each entry like the shipped ones
            for name in new_bands:
                config["reach"]["ranges"].setdefault(name, [0.0, 0.0])
        config = configuration.merge(config, given)
        population.refuse_in(config, "rhi reach")
    config = configuration.merge(config, configuration.nest(overrides or {}))
    configuration.validate(config)
    validate(config)
    return config


def attractor(config: dict) -> str:
    """"pixels" or "body": the configured one, or the model's (``Model.reach_attractor``) for "auto"."""
    chosen = config["reach"]["attractor"]
    return models.of(config).reach_attractor(config) if chosen == "auto" else chosen


def view(config: dict) -> bool:
    """Whether the camera sees the real arm: reach.view; "auto" = on for a model whose brain reads the seen arm's
    pose (``Model.sees_pose``), off for the others (the paper's)."""
    chosen = config["reach"]["view"]
    return models.of(config).sees_pose if chosen == "auto" else chosen == "on"


def validate(config: dict) -> None:
    """The [reach] keys: counts, bands, ranges inside the joint ranges the decoders know, the attractor."""
    reach = config["reach"]
    if reach["goals"] < 1:
        raise ConfigError(f"reach.goals must be at least 1, got {reach['goals']}")
    if reach["record_every"] < 1:
        raise ConfigError(f"reach.record_every must be at least 1 step, got {reach['record_every']}")
    for key in ("radius_cm", "precision_ratio"):
        if not reach[key] > 0:
            raise ConfigError(f"reach.{key} must be positive, got {reach[key]}")
    if reach["attractor"] not in ATTRACTORS:
        raise ConfigError(f"reach.attractor = {reach['attractor']!r} is not one of {', '.join(ATTRACTORS)}")
    if not reach["bands"]:
        raise ConfigError("reach.bands is empty: name at least one of reach.ranges")
    for band in reach["bands"]:
        if band not in reach["ranges"]:
            raise ConfigError(f"reach.bands: unknown band {band!r} (reach.ranges has {', '.join(reach['ranges'])})")
    if len(set(reach["bands"])) != len(reach["bands"]):
        raise ConfigError("reach.bands lists a band more than once")
    for band in reach["bands"]:
        check_range(band, reach["ranges"][band])
    if reach["view"] not in VIEWS:
        raise ConfigError(f"reach.view = {reach['view']!r} is not one of {', '.join(VIEWS)}")
    if attractor(config) == "pixels":  # the body-space attractor takes any positive ratio
        check_goal_variance(config, "reach.precision_ratio", reach["precision_ratio"])
    if models.of(config).sees_pose and reach["view"] == "off":
        raise ConfigError(f"reach.view = \"off\": the {models.of(config).name} model's brain needs the seen arm (its "
                          "pose encoder reads the camera); use \"on\" or \"auto\"")
    check_memory(config)


def check_goal_variance(config: dict, key: str, ratio: float) -> None:
    """The goal image's visual variance, decoder.visual_variance / ``ratio`` (the attractor image's Sigma_v / w),
    within the decoder's range (at least MIN_VISUAL_VARIANCE); a ConfigError naming ``key`` otherwise."""
    from rhi.components.vision.component import MIN_VISUAL_VARIANCE

    variance = config["decoder"]["visual_variance"] / ratio
    if not variance >= MIN_VISUAL_VARIANCE:
        raise ConfigError(f"{key} = {ratio:g} is too large: the goal image's visual variance, decoder.visual_variance "
                          f"/ {key} = {config['decoder']['visual_variance']:g} / {ratio:g} = {variance:g}, would be "
                          f"below the decoder's smallest, {MIN_VISUAL_VARIANCE:g}; use at most "
                          f"{config['decoder']['visual_variance'] / MIN_VISUAL_VARIANCE:g} (the released agent's is 2)")


def memory_needed(config: dict) -> int:
    """About how many bytes the reach of ``config`` needs at its peak: each decoder's reaches (reach.goals per
    band) run in one lockstep batch, recorded at every step, with two cameras (the goal's and the seen arm's),
    by the experiment's bounds per trial step and per batch pixel (:func:`rhi.master.config.memory_needed`)."""
    experiment, reaches = config["experiment"], config["reach"]["goals"] * len(config["reach"]["bands"])
    decoders = len(experiment["decoders"])
    recorded = (experiment["steps"] + 1) * reaches * decoders * configuration.BYTES_PER_TRIAL_STEP
    images = 2 * reaches * decoders * experiment["resolution"] ** 2 * configuration.BYTES_PER_BATCH_PIXEL
    return recorded + images


def check_memory(config: dict) -> None:
    """A ConfigError, before any work, for a reach that would need more memory than this machine has."""
    needed, available = memory_needed(config), configuration.physical_memory()
    if available and needed > available:
        experiment, reach = config["experiment"], config["reach"]
        raise ConfigError(f"this reach would need about {configuration.size(needed)} of memory "
                          f"({reach['goals']} goals x {len(reach['bands'])} bands x "
                          f"{len(experiment['decoders'])} decoders of {experiment['steps']} steps at "
                          f"{experiment['resolution']} x {experiment['resolution']} px), more than this machine's "
                          f"{configuration.size(available)}; lower reach.goals (--goals) or experiment.steps")


def check_range(band: str, values) -> None:
    """A band's [low, high] deg: two numbers, 0 <= low <= high, and every goal inside the joint ranges."""
    if not (isinstance(values, list) and len(values) == 2
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in values)):
        raise ConfigError(f"reach.ranges.{band} = {values!r} must be [low, high] in degrees")
    low, high = values
    if not 0 <= low <= high:
        raise ConfigError(f"reach.ranges.{band} = {values!r}: need 0 <= low <= high (deg from rest)")
    if high > min(HALF_RANGES):
        raise ConfigError(f"reach.ranges.{band} = {values!r}: goals up to {high:g} deg from rest leave the joint "
                          f"ranges the decoders know ({known_ranges()})")


def known_ranges() -> str:
    """The joint ranges the decoders are trained on, in words: rest ± HALF_RANGES per joint."""
    return f"shoulder rest ± {HALF_RANGES[0]:g} deg, elbow rest ± {HALF_RANGES[1]:g} deg"


def goal_problem(shoulder, elbow, names=("goal_shoulder", "goal_elbow")) -> str | None:
    """Why a goal pose (absolute joint angles, deg) cannot be reached to, or None: each joint finite and
    within rest ± HALF_RANGES, the ranges :func:`check_range` keeps a band's goals in."""
    for name, value, rest, half in zip(names, (shoulder, elbow), kinematics.REST_POSE, HALF_RANGES):
        value = np.asarray(value, dtype=float).reshape(-1)
        bad = ~(np.abs(value - rest) <= half)  # NaN too
        if bad.any():
            far = float(value[bad][0])
            return (f"{name} = {far:g} deg is {abs(far - rest):g} deg from rest ({rest:g} deg): it leaves the joint "
                    f"ranges the decoders know ({known_ranges()})")
    return None


# -- goals ---------------------------------------------------------------------------------------------------
def goal_seed(master_seed: int, band: str, index: int) -> int:
    """A stable 63-bit seed per goal; the same for both decoders, and a goal's draw is independent of the count."""
    digest = hashlib.sha256(f"{master_seed}/reach/{band}/{index}".encode()).digest()
    return int.from_bytes(digest[:8], "little") >> 1


def draw_offset(seed: int, low: float, high: float) -> tuple[float, float]:
    """One goal's offset from rest (deg per joint): |offset| ~ U[low, high), the sign + or - with equal odds.

    The released agent's law (model_operation/main_inference.py, reaching_tasks):
    ``np.random.uniform(low, high, (40, 2)) * (-2 * np.random.randint(0, 2, (40, 2)) + 1)``, here per goal
    from its own seeded generator.
    """
    generator = np.random.default_rng(seed)
    magnitude = generator.uniform(low, high, size=2)
    sign = 1 - 2 * generator.integers(0, 2, size=2)
    return float(magnitude[0] * sign[0]), float(magnitude[1] * sign[1])


def plan(config: dict) -> list[ReachTrial]:
    """Every reach, in order: decoder, band, index."""
    reach, seed = config["reach"], config["experiment"]["seed"]
    trials = []
    for decoder in config["experiment"]["decoders"]:
        for band in reach["bands"]:
            low, high = reach["ranges"][band]
            for index in range(reach["goals"]):
                goal = goal_seed(seed, band, index)
                trials.append(ReachTrial(decoder, band, index, goal, *draw_offset(goal, low, high)))
    return trials


# -- the system ----------------------------------------------------------------------------------------------
def links(kind: str, view: bool, pixel_decoder: bool) -> list[tuple[str, str]]:
    """The reach system's connections, in step order; ``kind`` = "pixels" or "body" (the goal's term)."""
    connections = [("goal.pose", "goal_camera.arm_pose")]
    if kind == "pixels":
        connections += [("goal_camera.image", "goal_decoder.image"), ("brain.mu", "goal_decoder.mu"),
                        ("goal_decoder.visual_drive", "brain.goal_drive"),
                        ("goal_decoder.visual_error", "brain.goal_error"),
                        ("goal_decoder.visual_stiffness", "brain.goal_stiffness")]
    else:
        connections += [("goal_camera.image", "goal_encoder.image"), ("goal_encoder.pose", "goal_attractor.goal_pose"),
                        ("goal_encoder.pose_variance", "goal_attractor.goal_pose_variance"),
                        ("brain.mu", "goal_attractor.mu"), ("goal_attractor.goal_drive", "brain.goal_drive"),
                        ("goal_attractor.goal_error", "brain.goal_error"),
                        ("goal_attractor.goal_stiffness", "brain.goal_stiffness")]
    if view:
        connections += [("body.q_shoulder", "arm_pose.q_shoulder"), ("body.q_elbow", "arm_pose.q_elbow"),
                        ("arm_pose.pose", "camera.arm_pose")]
        if pixel_decoder:
            connections += [("camera.image", "decoder.image"), ("brain.mu", "decoder.mu"),
                            ("decoder.visual_drive", "brain.visual_drive"),
                            ("decoder.visual_error", "brain.visual_error"),
                            ("decoder.visual_stiffness", "brain.visual_stiffness")]
    return connections + [("body.q_shoulder", "brain.q_shoulder"), ("body.q_elbow", "brain.q_elbow"),
                          ("brain.u_shoulder", "body.u_shoulder"), ("brain.u_elbow", "body.u_elbow")]


def pixel_decoder_seen(config: dict) -> bool:
    """Whether a decoder reads the camera's image of the real arm (when it is seen): when the model's brain reads
    the pixel term (``Model.reads_pixels``)."""
    return models.of(config).reads_pixels(config)


def connections(config: dict) -> list[tuple[str, str]]:
    """The reach task's links under ``config`` (:func:`links`; the model's follow them, :func:`build`)."""
    return links(attractor(config), view(config), pixel_decoder_seen(config))


def scenario(kind: str, path: str, config: dict, threads: int = 1, extra=()) -> Scenario:
    """The reach task of decoder ``kind`` (checkpoint ``path``) as data: the goal's arm and camera and its term
    (:func:`links`), the seen arm and its camera when in view, before the model; the free body after it;
    :data:`RECORD`, the goal's hand and the ``extra`` paths recorded."""
    from rhi.master.decoders.cache import check_kind, decoder_component, loaded

    resolution = config["experiment"]["resolution"]
    check_kind(kind, path, loaded(path, resolution, config["camera"]["blur"]))  # whether or not a decoder is used

    def decoder(name):
        return decoder_component(kind, path, config, threads=threads, name=name)

    world = [PosedArm("goal"), Camera("goal_camera", resolution=resolution)]
    if attractor(config) == "pixels":
        world.append(decoder("goal_decoder"))
    else:
        from rhi.components.brain.goal import GoalAttractor
        world += [pose_encoders(config, kind, threads)("goal_encoder"), GoalAttractor()]
    if view(config):
        world += [JointPose("arm_pose"), Camera("camera", resolution=resolution)]
        if pixel_decoder_seen(config):
            world.append(decoder("decoder"))
    return Scenario(world=tuple(world), body=(ArmPlant(),), links=tuple(connections(config)), record=(*RECORD, "goal.hand", *extra), kind=kind, threads=threads)


def build_system(kind: str, path: str, config: dict, threads: int = 1) -> System:
    """The reach system of decoder ``kind`` (checkpoint ``path``) under ``config`` (:func:`scenario`)."""
    return build(scenario(kind, path, config, threads), config)


def parameters(trials: list[ReachTrial], config: dict, system: System) -> dict:
    """Every parameter of the reach system: the experiment's sources for the body, cameras and decoders
    (:data:`rhi.master.config.sources.TASK_SOURCES`), the model's for its brain, the goal per trial, and the
    goal's precision."""
    given = shared_parameters(config, ("body", "camera", "decoder"))
    for key in ("blur", "ball_radius"):
        given[f"goal_camera.{key}"] = config["camera"][key]
    given["goal.shoulder"] = np.array([t.goal_pose[0] for t in trials])
    given["goal.elbow"] = np.array([t.goal_pose[1] for t in trials])
    ratio = config["reach"]["precision_ratio"]
    if "goal_decoder" in system.components:  # the attractor image: Sigma_v / w, the released agent's sigma_mu
        given["goal_decoder.visual_variance"] = config["decoder"]["visual_variance"] / ratio
    if "goal_attractor" in system.components:
        given["goal_attractor.precision_ratio"] = ratio
    given.update(model_parameters(config, [t.seed for t in trials], lambda key: per_trial(trials, config, key)))
    return declared(given, system)


def run_reaches(kind: str, path: str, trials: list[ReachTrial], config: dict, threads: int = 1, progress=None,
                extra=()):
    """Run ``trials`` (all of decoder ``kind``) in lockstep; returns the master's Result (RECORD, the goal's
    hand and the ``extra`` paths recorded)."""
    return run(scenario(kind, path, config, threads, extra), config, lambda system: parameters(trials, config, system),
               len(trials), progress)


# -- measures --------------------------------------------------------------------------------------------------
def measures(result) -> dict[str, np.ndarray]:
    """Per step and trial (steps + 1, B): the hand, its distance to the goal hand (cm), the belief's, and more."""
    values = result.values
    goal = values["goal.hand"][0]  # (B, 2): the goal does not move
    hand_x, hand_y = values["body.hand_x"], values["body.hand_y"]
    mu = values["brain.mu"]
    seen_x, seen_y = kinematics.forward(mu[..., 0], mu[..., 1])
    return {
        "hand_x_m": hand_x, "hand_y_m": hand_y,
        "goal_x_m": np.broadcast_to(goal[:, 0], hand_x.shape), "goal_y_m": np.broadcast_to(goal[:, 1], hand_x.shape),
        "distance_cm": 100.0 * np.hypot(hand_x - goal[:, 0], hand_y - goal[:, 1]),
        "belief_distance_cm": 100.0 * np.hypot(seen_x - goal[:, 0], seen_y - goal[:, 1]),
        "mu_shoulder_deg": mu[..., 0], "mu_elbow_deg": mu[..., 1],
        "s_p_shoulder_deg": values["body.q_shoulder"], "s_p_elbow_deg": values["body.q_elbow"],
        "action_shoulder_deg_s": values["brain.u_shoulder"], "action_elbow_deg_s": values["brain.u_elbow"],
        "gamma": values["brain.gamma"], "free_energy": values["brain.free_energy"],
    }


def time_to_reach(times: np.ndarray, distance_cm: np.ndarray, radius_cm: float) -> np.ndarray:
    """Per trial (B,): the first time from which the hand stays within ``radius_cm`` of the goal to the end
    (NaN where it ends outside). distance_cm: (steps + 1, B)."""
    inside = distance_cm <= radius_cm
    outside_from_end = np.flip(~inside, axis=0)
    last_outside = len(times) - 1 - np.argmax(outside_from_end, axis=0)  # index of the last step outside
    first = np.where(outside_from_end.any(axis=0), last_outside + 1, 0)
    return np.where(inside[-1], np.asarray(times)[np.minimum(first, len(times) - 1)], np.nan)


def path_length_cm(hand_x: np.ndarray, hand_y: np.ndarray) -> np.ndarray:
    """Per trial (B,): the length of the hand's path, the sum of its straight steps, cm."""
    return 100.0 * np.hypot(np.diff(hand_x, axis=0), np.diff(hand_y, axis=0)).sum(axis=0)


def outcomes(times: np.ndarray, per_step: dict[str, np.ndarray], radius_cm: float) -> dict[str, np.ndarray]:
    """Per trial (B,): start and final distance (cm), reached, time to reach (s), path length (cm), and
    whether it ended farther from the goal than it started."""
    distance = per_step["distance_cm"]
    return {"start_distance_cm": distance[0], "final_distance_cm": distance[-1],
            "reached": distance[-1] <= radius_cm, "time_to_reach_s": time_to_reach(times, distance, radius_cm),
            "path_length_cm": path_length_cm(per_step["hand_x_m"], per_step["hand_y_m"]),
            "farther_than_start": distance[-1] > distance[0],
            "final_belief_distance_cm": per_step["belief_distance_cm"][-1]}
