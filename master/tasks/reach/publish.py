"""The reach as a registered task (:class:`Reach`): every decoder's reaches in lockstep, then summary.csv, goals.csv,
trials.csv and figures/ (docs/reach.md); the hooks an agent FMU and an SSP package of it need (a parameter file
per goal, ``conv_near_0``)."""
from __future__ import annotations

import time

import numpy as np

from rhi.master import models
from rhi.master.cosim import ConfigError, SimulationError
from rhi.master.tasks.reach import task as reach
from rhi.master.decoders.cache import check_decoders, ensure_checkpoints
from rhi.master.decoders.cache import pose_encoder_path
from rhi.master.runtime.pool import JOB_THREADS, Workers, run_jobs
from rhi.master.tasks.illusion.runner import bar_positions, step_bar, without_failures
from rhi.master.outputs import tables
from rhi.master.tasks.agent_ports import body_links
from rhi.master.tasks.base import Task, TaskResult

# The released agent's reaching logs (thomasroodnl/active-inference-rhi, active-inference-agent/model_operation/
# operation_logs/reach_results, 40 runs per file set): the runs whose last logged cartesian_distance is under
# 1 cm, and those whose last distance exceeds their first. "s2nr2u" is its ConvDecoder, "vae" its VAE.
RELEASED_AGENT = {("conv", "near"): (40, 0), ("conv", "far"): (12, 12), ("vae", "near"): (40, 0),
                  ("vae", "far"): (11, 12)}
RELEASED_AGENT_GOALS = 40

SUMMARY_COLUMNS = ["decoder", "band", "n_goals", "n_reached", "reached_fraction", "radius_cm",
                   "start_distance_cm_mean", "final_distance_cm_mean", "final_distance_cm_sd",
                   "final_distance_cm_median", "time_to_reach_s_mean", "path_length_cm_mean",
                   "n_farther_than_start", "released_agent_reached", "released_agent_farther", "released_agent_goals"]
GOAL_COLUMNS = ["decoder", "band", "goal", "seed", "goal_shoulder_offset_deg", "goal_elbow_offset_deg",
                "start_distance_cm", "final_distance_cm", "reached", "time_to_reach_s", "path_length_cm",
                "farther_than_start", "final_belief_distance_cm"]
STEP_KEYS = ["hand_x_m", "hand_y_m", "distance_cm", "belief_distance_cm", "mu_shoulder_deg", "mu_elbow_deg",
             "s_p_shoulder_deg", "s_p_elbow_deg", "action_shoulder_deg_s", "action_elbow_deg_s", "gamma"]


def decoder_reaches(config: dict, kind: str, path: str, trials: list, position: int | None = None):
    """One decoder's reaches in one lockstep batch (a job): (kept trials, times, per-step measures, seconds,
    {failed trial: error})."""
    def run_trials(batch):
        with step_bar(f"{kind} reaches x{len(batch)}", config["experiment"]["steps"], position) as update:
            return reach.run_reaches(kind, path, batch, config, JOB_THREADS, update)

    began = time.perf_counter()
    try:
        result, kept, failed = without_failures(run_trials, trials)
    except SimulationError as error:
        failed, result, kept = {**error.failures, **{t: str(error) for t in trials}}, None, []
    if result is None:
        return kept, None, None, time.perf_counter() - began, failed
    return kept, result.times, reach.measures(result), time.perf_counter() - began, failed


def summary_rows(trials, final: dict[str, np.ndarray], radius_cm: float) -> list[list]:
    """One row per decoder x band (:data:`SUMMARY_COLUMNS`)."""
    rows = []
    for (decoder, band), members in tables.cells(trials, key=lambda t: (t.decoder, t.band)).items():
        pick = {key: np.asarray(values)[members] for key, values in final.items()}
        reached = pick["reached"].astype(bool)
        released, farther = RELEASED_AGENT.get((decoder, band), (None, None))
        mean = lambda values: tables.number(np.mean(values)) if len(values) else ""  # noqa: E731
        sd = tables.mean_sd(pick["final_distance_cm"])[1]
        rows.append([decoder, band, len(members), int(reached.sum()), tables.number(reached.mean()),
                     tables.number(radius_cm), mean(pick["start_distance_cm"]), mean(pick["final_distance_cm"]),
                     tables.number(sd), tables.number(np.median(pick["final_distance_cm"])),
                     mean(pick["time_to_reach_s"][reached]), mean(pick["path_length_cm"]),
                     int(pick["farther_than_start"].sum()), "" if released is None else released,
                     "" if farther is None else farther, "" if released is None else RELEASED_AGENT_GOALS])
    return rows


def goal_rows(trials, final: dict[str, np.ndarray]) -> list[list]:
    """One row per reach (:data:`GOAL_COLUMNS`)."""
    def cell(value):
        return int(value) if isinstance(value, (bool, np.bool_)) else tables.number(value)
    return [[t.decoder, t.band, t.index, t.seed, tables.number(t.shoulder_offset), tables.number(t.elbow_offset),
             *(cell(final[key][i]) for key in GOAL_COLUMNS[6:])] for i, t in enumerate(trials)]


def trials_text(trials, times, per_step: dict[str, np.ndarray], every: int) -> str:
    """trials.csv: one row per reach x recorded step (every ``every`` steps, and the last)."""
    steps = sorted(set(range(0, len(times), every)) | {len(times) - 1})
    rows = [[t.decoder, t.band, t.index, tables.number(times[s]), *(tables.number(per_step[key][s, i])
                                                                     for key in STEP_KEYS)]
            for i, t in enumerate(trials) for s in steps]
    return tables.csv_text(["decoder", "band", "goal", "time_s", *STEP_KEYS], rows)


class Reach(Task):
    """The free arm reaching to a seen goal, near and far (docs/reach.md)."""

    name = "reach"
    summary = "the free arm reaching to a seen goal, near and far"
    settings = "reach.toml"
    command = "rhi reach"
    # the FMI export hooks
    agent, model_name = "rhi.master.export.reach_agent:ReachAgent", "ReachAgent"
    system_name, system_description = "RubberHandReach", "the reach agent and a free body"
    trial_form = "BAND/INDEX, e.g. near/0"

    def load(self, path=None, overrides: dict | None = None, quick: bool = False, model_name: str = "paper") -> dict:
        """The reach's configuration (:func:`rhi.master.tasks.reach.task.load`)."""
        return reach.load(path, quick=quick, model_name=model_name, overrides=overrides)

    def plan(self, config: dict) -> list:
        """Every reach (:func:`rhi.master.tasks.reach.task.plan`)."""
        return reach.plan(config)

    def scenario(self, config: dict, kind: str, trials=(), checkpoint: str | None = None):
        """The reach system of decoder ``kind`` (:func:`rhi.master.tasks.reach.task.scenario`)."""
        from rhi.master.decoders.cache import checkpoint_path
        return reach.scenario(kind, checkpoint or checkpoint_path(kind, config, must_exist=True), config, JOB_THREADS)

    def parameters(self, trials: list, config: dict, system) -> dict:
        """The reaches' parameters (:func:`rhi.master.tasks.reach.task.parameters`)."""
        return reach.parameters(trials, config, system)

    def measures(self, result, config: dict, trials: list) -> dict:
        """The hand, its distance to the goal and more per step (:func:`rhi.master.tasks.reach.task.measures`)."""
        return reach.measures(result)

    def check_before_work(self, config: dict, context) -> None:
        """The decoders' checkpoints or training settings, and the pose encoders the wiring reads."""
        check_decoders(config)
        for kind in config["experiment"]["decoders"]:  # the encoders and the wiring, before any work
            if reach.attractor(config) == "body" or models.of(config).sees_pose:
                pose_encoder_path(kind, config)

    def simulate(self, config: dict, context, workers=None) -> TaskResult:
        """Each decoder's reaches in one lockstep batch, side by side on ``workers``, failures isolated."""
        if workers is None:
            with Workers() as own:
                return self.simulate(config, context, own)
        began, trials = time.perf_counter(), reach.plan(config)
        checkpoints, training_seconds = ensure_checkpoints(config, progress=context.progress, workers=workers)
        kinds = config["experiment"]["decoders"]
        jobs = [(config, kind, checkpoints[kind], [t for t in trials if t.decoder == kind], position)
                for kind, position in zip(kinds, bar_positions(len(kinds), context.progress, None, workers))]
        kept, blocks, seconds, failures, times = [], [], {}, {}, None
        for kind, (batch, batch_times, per_step, spent, failed) in zip(kinds, run_jobs(decoder_reaches, jobs,
                                                                                        workers=workers)):
            seconds[kind] = spent
            failures.update(failed)
            if per_step is not None:
                kept += batch
                blocks.append(per_step)
                times = batch_times
        if not blocks:
            raise SimulationError("reach", 0.0, "every reach failed: " + "; ".join(sorted(set(failures.values()))))
        per_step = {key: np.concatenate([block[key] for block in blocks], axis=1) for key in blocks[0]}
        provenance = {
            "command": "rhi reach", "task": self.name,
            "model": models.of(config).name, "attractor": reach.attractor(config),
            "configuration": config, "checkpoints": checkpoints,
            "seeds": {"master": config["experiment"]["seed"], "goals": [t.__dict__ for t in kept]},
            "released_agent": {f"{d}/{b}": {"reached": r, "farther_than_start": f, "goals": RELEASED_AGENT_GOALS}
                               for (d, b), (r, f) in RELEASED_AGENT.items()},
            "timings_s": {"training": training_seconds, "reaches": seconds},
            "failed_trials": [{**trial.__dict__, "error": error} for trial, error in failures.items()],
        }
        return TaskResult(self, config, kept, times, per_step, provenance, failures, began)

    def outcomes(self, result: TaskResult) -> dict:
        """Per reach: :func:`rhi.master.tasks.reach.task.outcomes`."""
        return reach.outcomes(result.times, result.per_step, result.config["reach"]["radius_cm"])

    def tables(self, result: TaskResult) -> dict:
        """summary.csv (per decoder x band), goals.csv (per reach), trials.csv (per reach x recorded step)."""
        radius, final = result.config["reach"]["radius_cm"], self.outcomes(result)
        return {"summary.csv": tables.csv_text(SUMMARY_COLUMNS, summary_rows(result.trials, final, radius)),
                "goals.csv": tables.csv_text(GOAL_COLUMNS, goal_rows(result.trials, final)),
                "trials.csv": trials_text(result.trials, result.times, result.per_step,
                                          result.config["reach"]["record_every"])}

    def figures(self, result: TaskResult, folder) -> list[str]:
        """figures/: the reaches' paths and distances (:func:`rhi.master.tasks.reach.figures.write_figures`)."""
        from rhi.master.tasks.reach.figures import write_figures

        (folder / "figures").mkdir()
        write_figures(folder / "figures", result.trials, result.times, result.per_step, self.outcomes(result),
                      result.config["reach"]["radius_cm"])
        return sorted(path.name for path in (folder / "figures").iterdir())

    # -- the FMI export hooks ---------------------------------------------------------------------------------
    def trials(self, config: dict, kind: str) -> list:
        """The reach plan's goals for decoder ``kind`` (the same goals for each decoder)."""
        return reach.plan({**config, "experiment": {**config["experiment"], "decoders": [kind]}})

    def trial_name(self, trial) -> str:
        """``conv_near_0``: a goal's parameter file, without folder and suffix."""
        return f"{trial.decoder}_{trial.band}_{trial.index}"

    def parse_trial(self, text: str, config: dict, kind: str):
        """``near/0`` -> the reach plan's goal of decoder ``kind`` (ConfigError naming what is unknown)."""
        parts = text.split("/")
        if len(parts) != 2 or not parts[1].isdigit():
            raise ConfigError(f"--trial {text!r} must be {self.trial_form}")
        band, index = parts[0], int(parts[1])
        if band not in config["reach"]["bands"]:
            raise ConfigError(f"--trial {text!r}: no band {band!r} (have: {', '.join(config['reach']['bands'])})")
        if index >= config["reach"]["goals"]:
            raise ConfigError(f"--trial {text!r}: no goal {index} (reach.goals = {config['reach']['goals']})")
        return next(t for t in self.trials(config, kind) if (t.band, t.index) == (band, index))

    def links(self, config: dict) -> list[tuple[str, str]]:
        """The body's links in the reach system (the sensed joints in, the action out)."""
        return body_links(reach.connections(config))

    def agent_values(self, trial, config: dict, declared: dict, starts: dict) -> dict:
        """Every parameter of the reach agent FMU at its start (the configuration's, which built it), the goal
        pose the trial's: ``{name: (type, value)}``."""
        values = {name: (kind, starts[name]) for name, (causality, kind) in declared.items() if causality == "parameter"}
        values["goal_shoulder"], values["goal_elbow"] = ("Real", trial.goal_pose[0]), ("Real", trial.goal_pose[1])
        return values
