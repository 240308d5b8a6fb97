"""The rubber-hand experiment: wire the system, run the protocol in batches, measure, write.

One batch per decoder: every condition x stimulation x trial of that decoder
advances together (the batch dimension), so one decoder call serves them all.
"""
from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass

import numpy as np

from components.body import kinematics
from components.body.camera import Camera
from components.body.plant import ArmPlant
from components.body.rubber_arm import RubberArm
from components.brain.integrator import Brain
from components.stimulus import Stimulus
from master.algorithm import simulate
from master.errors import SimulationError
from master.system import System

# Gauss-Seidel order within one step (DESIGN.md): the decoder reads the brain's mu of time t and the
# image of time t; the brain then integrates; the body finally receives the new action.
CONNECTIONS = [
    ("rubber_arm.hand", "stimulus.target"),
    ("rubber_arm.pose", "camera.arm_pose"),
    ("stimulus.ball", "camera.ball"),
    ("camera.image", "decoder.image"),
    ("brain.mu", "decoder.mu"),
    ("decoder.visual_drive", "brain.visual_drive"),
    ("decoder.visual_error", "brain.visual_error"),
    ("decoder.visual_stiffness", "brain.visual_stiffness"),
    ("stimulus.visual_time", "brain.visual_time"),
    ("stimulus.tactile_time", "brain.tactile_time"),
    ("body.q_shoulder", "brain.q_shoulder"),
    ("body.q_elbow", "brain.q_elbow"),
    ("brain.u_shoulder", "body.u_shoulder"),
    ("brain.u_elbow", "body.u_elbow"),
]

RECORD = ["brain.mu", "brain.gamma", "brain.u_shoulder", "brain.u_elbow", "brain.action_rate",
          "brain.free_energy", "body.q_shoulder", "body.q_elbow", "body.hand_x", "body.hand_y",
          "body.force_x", "body.force_y", "stimulus.visual_time", "stimulus.tactile_time",
          "decoder.visual_error", "stimulus.ball"]


@dataclass(frozen=True)
class Trial:
    """One trial of the protocol and everything that makes it differ from the others."""

    decoder: str
    condition: str
    stimulation: str
    index: int
    seed: int
    offset_x: float
    delay_min: float
    delay_max: float


def trial_seed(master_seed: int, condition: str, stimulation: str, index: int) -> int:
    """A stable 63-bit seed per trial. Independent of the decoder, so both decoders see the same delays."""
    digest = hashlib.sha256(f"{master_seed}/{condition}/{stimulation}/{index}".encode()).digest()
    return int.from_bytes(digest[:8], "little") >> 1


def plan(config: dict) -> list[Trial]:
    """Every trial of the protocol, in a fixed order: decoder, condition, stimulation, index."""
    experiment = config["experiment"]
    return [Trial(decoder, condition, stimulation, index,
                  trial_seed(experiment["seed"], condition, stimulation, index),
                  float(config["conditions"][condition]),
                  float(config["stimulations"][stimulation]["delay_min"]),
                  float(config["stimulations"][stimulation]["delay_max"]))
            for decoder in experiment["decoders"]
            for condition in experiment["conditions"]
            for stimulation in experiment["stimulations"]
            for index in range(experiment["trials"])]


def rubber_pose(offset_x: float, offset_y: float = 0.0) -> tuple[float, float]:
    """Joint angles (deg) of the rubber arm whose hand is offset from the real resting hand."""
    shoulder, elbow = kinematics.inverse(kinematics.REST_HAND[0] + offset_x, kinematics.REST_HAND[1] + offset_y)
    return float(shoulder), float(elbow)


def build_system(decoder, config: dict, body=None) -> System:
    """The rubber-hand system around a decoder component; ``body`` defaults to the native pymunk plant."""
    resolution = config["experiment"]["resolution"]
    components = [RubberArm(), Stimulus(), Camera(resolution=resolution), decoder, Brain(),
                  body if body is not None else ArmPlant()]
    return System(components, CONNECTIONS)


def parameters(trials: list[Trial], config: dict) -> dict:
    """Per-trial and shared parameters, as ``component.variable`` paths."""
    column = lambda attribute: np.array([getattr(t, attribute) for t in trials])  # noqa: E731
    brain, body = config["brain"], config["body"]
    return {
        "rubber_arm.offset_x": column("offset_x"),
        "stimulus.period": config["stimulus"]["period"],
        "stimulus.delay_min": column("delay_min"),
        "stimulus.delay_max": column("delay_max"),
        "stimulus.seed": column("seed").astype(np.int64),
        "decoder.visual_variance": config["decoder"]["visual_variance"],
        "brain.mu0": np.array(kinematics.REST_POSE, dtype=float),
        "brain.proprioceptive_variance": brain["proprioceptive_variance"],
        "brain.gamma0": brain["gamma0"],
        "brain.sync_sd": brain["sync_sd"],
        "brain.async_density": brain["async_density"],
        "brain.decay_rate": brain["decay_rate"],
        "body.held": bool(body["held"]),
        "body.substeps": int(body["substeps"]),
    }


def run_batch(decoder, trials: list[Trial], config: dict, body=None, progress=None):
    """Run ``trials`` (all with this decoder component) in lockstep; returns the master's Result."""
    experiment = config["experiment"]
    system = build_system(decoder, config, body)
    return simulate(system, stop_time=experiment["steps"] * experiment["step_size"],
                    step_size=experiment["step_size"], scheme=experiment["scheme"], batch_size=len(trials),
                    parameters=parameters(trials, config), record=RECORD, progress=progress)


def measures(result) -> dict[str, np.ndarray]:
    """Per step and trial (shape steps+1 x B): drift (cm), force (N), attempted hand velocity, and the rest.

    Drift = x of the perceived hand (forward kinematics of mu) minus x of the real hand, in cm;
    negative is to the left (DESIGN.md, Measures).
    """
    values = result.values
    mu = values["brain.mu"]
    perceived_x, _ = kinematics.forward(mu[..., 0], mu[..., 1])
    real_x, _ = kinematics.forward(values["body.q_shoulder"], values["body.q_elbow"])
    jacobian = kinematics.jacobian(values["body.q_shoulder"], values["body.q_elbow"])  # m/deg
    attempted = np.einsum("...ij,...j->...i", jacobian, values["brain.action_rate"])
    return {
        "drift_cm": 100.0 * (perceived_x - real_x),
        "force_x_n": values["body.force_x"],
        "force_y_n": values["body.force_y"],
        "gamma": values["brain.gamma"],
        "mu_shoulder_deg": mu[..., 0],
        "mu_elbow_deg": mu[..., 1],
        "s_p_shoulder_deg": values["body.q_shoulder"],
        "s_p_elbow_deg": values["body.q_elbow"],
        "action_shoulder_deg_s": values["brain.u_shoulder"],
        "action_elbow_deg_s": values["brain.u_elbow"],
        "action_rate_shoulder": values["brain.action_rate"][..., 0],
        "action_rate_elbow": values["brain.action_rate"][..., 1],
        "attempted_hand_vx_m_s": attempted[..., 0],
        "visual_time_s": values["stimulus.visual_time"],
        "tactile_time_s": values["stimulus.tactile_time"],
        "visual_error": values["decoder.visual_error"],
        "free_energy": values["brain.free_energy"],
        "ball_x_m": values["stimulus.ball"][..., 0],
        "ball_y_m": values["stimulus.ball"][..., 1],
    }


def without_failures(run_trials, trials: list[Trial]):
    """``run_trials(trials)``, dropping any trial a component blames for a failed step.

    A component that names the failing trials (``StepFailure(trials=...)``, e.g. the FMU adapter on a
    NaN) costs only those: they are recorded and the rest of the batch is run again from the start,
    which gives them exactly the numbers they would have had (trials are independent). A failure
    that names no trial stops the run. Returns (result or None, kept trials, {trial: error}).
    """
    failures: dict[Trial, str] = {}
    while trials:
        try:
            return run_trials(trials), trials, failures
        except SimulationError as error:
            if not error.trials:
                raise
            for position in error.trials:
                failures[trials[position]] = str(error)
            trials = [t for position, t in enumerate(trials) if position not in error.trials]
    return None, trials, failures


def run(config: dict, checkpoints: dict[str, str], body_factory=None, progress: bool = False):
    """Every trial of the protocol, one lockstep batch per decoder.

    Returns (trials, times, per_step, seconds, failures): ``per_step[key]`` has shape
    (steps + 1, n_trials) in the order of ``trials`` (the protocol's order, less any failed trial);
    ``failures`` maps each failed trial to its error.
    """
    from master.decoders import decoder_component  # torch is imported only when a run needs it

    kept, blocks, seconds, failures, times = [], [], {}, {}, None
    protocol = plan(config)
    for kind in config["experiment"]["decoders"]:
        def run_trials(batch, kind=kind):
            bar = progress_bar(f"{kind} trials x{len(batch)}", config["experiment"]["steps"]) if progress else None
            body = body_factory() if body_factory else None
            try:
                return run_batch(decoder_component(kind, checkpoints[kind], config), batch, config, body,
                                 bar.update_to if bar else None)
            finally:
                if bar:
                    bar.close()

        began = time.perf_counter()
        result, batch, failed = without_failures(run_trials, [t for t in protocol if t.decoder == kind])
        seconds[kind] = time.perf_counter() - began
        failures.update(failed)
        if result is not None:
            kept += batch
            blocks.append(measures(result))
            times = result.times
    if not blocks:
        raise SimulationError("experiment", 0.0, "every trial failed: " + "; ".join(sorted(set(failures.values()))))
    per_step = {key: np.concatenate([block[key] for block in blocks], axis=1) for key in blocks[0]}
    return kept, times, per_step, seconds, failures


def trial_outcome(config: dict, decoder: str, condition: str, stimulation: str, index: int,
                  checkpoint: str | None = None) -> dict:
    """Run ONE trial (a sweep's task) and return its end-of-trial values.

    The decoder checkpoint is ``checkpoint`` or the one the configuration names or caches; it must
    exist already (sweeps train nothing on the workers).
    """
    from master.decoders import checkpoint_path, decoder_component

    experiment = config["experiment"]
    trial = Trial(decoder, condition, stimulation, index, trial_seed(experiment["seed"], condition, stimulation, index),
                  float(config["conditions"][condition]),
                  float(config["stimulations"][stimulation]["delay_min"]),
                  float(config["stimulations"][stimulation]["delay_max"]))
    path = checkpoint or checkpoint_path(decoder, config, must_exist=True)
    final = {key: float(value[-1, 0]) for key, value in
             measures(run_batch(decoder_component(decoder, path, config), [trial], config)).items()}
    return {"drift_cm": final["drift_cm"], "force_n": final["force_x_n"], "gamma_final": final["gamma"],
            "seed": trial.seed, **{k: v for k, v in final.items() if k not in ("drift_cm", "force_x_n", "gamma")}}


def progress_bar(description: str, total: int):
    from tqdm import tqdm

    bar = tqdm(total=total, desc=description, unit="step", leave=False)
    bar.update_to = lambda done, _total: bar.update(done - bar.n)
    return bar
