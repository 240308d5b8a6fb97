"""What a trial measures (docs/design.md, Measures), per step and trial, from the recorded outputs."""
from __future__ import annotations

import numpy as np

from rhi.components.body import kinematics
from rhi.master.outputs.tables import probe_name

def measures(result, model=None) -> dict[str, np.ndarray]:
    """Per step and trial (shape steps+1 x B): drift (cm), force (N), the action measure, and the rest, and
    ``model``'s own measures (:attr:`rhi.master.models.base.Model.measures`: a column per recorded output).

    Drift = x of the perceived hand (forward kinematics of mu) minus x of the real hand, in cm;
    negative is to the left (docs/design.md, Measures). The action measure of the paper's Fig. 3 d-f,
    ``action_accel_x_m_s2``, is the horizontal hand acceleration J a_dot: eq. 7's a_dot (deg/s^2)
    through the arm Jacobian at the sensed angles (m/deg), in m/s^2; 0 in row 0, before any step.
    Every key ends in its unit (none: dimensionless); docs/configuration.md lists them (from this function).
    ``visual_error`` is NaN where no decoder ran (a model that reads no pixel term, :func:`rhi.master.tasks.scene.build`).
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
        "action_rate_shoulder_deg_s2": values["brain.action_rate"][..., 0],
        "action_rate_elbow_deg_s2": values["brain.action_rate"][..., 1],
        "visual_time_s": values["stimulus.visual_time"],
        "tactile_time_s": values["stimulus.tactile_time"],
        "visual_error": values.get("decoder.visual_error", np.full_like(values["brain.gamma"], np.nan)),
        "free_energy": values["brain.free_energy"],
        "ball_x_m": values["stimulus.ball"][..., 0],
        "ball_y_m": values["stimulus.ball"][..., 1],
        "action_accel_x_m_s2": attempted[..., 0],
        **{column: values[path] for column, path in (model.measures if model else {}).items()},
    }


def half_time(times: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Per trial (B,): the first time at which ``values`` (steps+1 x B) reaches half its final value.

    Reaching means ``values / final >= 1/2`` (so a negative drift counts by its size). NaN where
    the final value is 0 (nothing to reach).
    """
    final = values[-1]
    with np.errstate(invalid="ignore", divide="ignore"):
        reached = values / np.where(final == 0, np.nan, final) >= 0.5
    first = np.argmax(reached, axis=0)
    return np.where(reached.any(axis=0), np.asarray(times)[first], np.nan)


def half_decay(times: np.ndarray, drift: np.ndarray, tactile_time: np.ndarray) -> np.ndarray:
    """Per trial (B,): seconds from the last touch until the drift first falls to half its value then.

    The last touch is the last tactile event observed (``tactile_time`` of the last row); falling means
    ``drift / drift at the last touch <= 1/2``. NaN where there was no touch, no drift at it, or the
    drift never halves before the trial ends (the persistence protocol's measure).
    """
    times = np.asarray(times)
    last = tactile_time[-1]
    result = np.full(drift.shape[1], np.nan)
    for trial in range(drift.shape[1]):
        if not np.isfinite(last[trial]):
            continue
        start = int(np.searchsorted(times, last[trial] - 1e-9))
        if start >= len(times) or drift[start, trial] == 0:
            continue
        fallen = np.flatnonzero(drift[start:, trial] / drift[start, trial] <= 0.5)
        if fallen.size:
            result[trial] = times[start + fallen[0]] - last[trial]
    return result


PROBE_TOLERANCE = 1e-9  # s: a probe at 60.0 is read at the step ending at 60.0 - 1e-12 (float ticks), as an event is


def probes(times: np.ndarray, drift: np.ndarray, probe_times) -> dict[str, np.ndarray]:
    """Per trial (B,): the drift (cm) read at each of ``probe_times`` (s), as a participant's pointing would read
    the felt hand then: the row of the first communication step that ends at or after the time (the rule by
    which an event is observed, components/stimulus.py), under :func:`rhi.master.outputs.tables.probe_name`."""
    times = np.asarray(times)
    rows = np.minimum(np.searchsorted(times, np.asarray(probe_times, dtype=float) - PROBE_TOLERANCE), len(times) - 1)
    return {probe_name(time): drift[row] for time, row in zip(probe_times, rows)}


def end_of_trial(times: np.ndarray, per_step: dict[str, np.ndarray], probe_times=()) -> dict[str, np.ndarray]:
    """Per trial (B,): every measure's value after the last step, and the measures of a whole trial.

    ``action_accel_mean_x_m_s2``: the action measure's mean over the steps (rows 1..steps, the
    values the brain computed; row 0 is the initial 0), the paper's Fig. 3 d. ``drift_half_time_s``:
    when the drift first reaches half its final value (:func:`half_time`), the illusion's time course.
    ``drift_at_<t>s_cm``: the drift at each of ``probe_times`` (s, ``experiment.probe_times``; :func:`probes`).
    """
    final = {key: values[-1] for key, values in per_step.items()}
    final["action_accel_mean_x_m_s2"] = per_step["action_accel_x_m_s2"][1:].mean(axis=0)
    final["drift_half_time_s"] = half_time(times, per_step["drift_cm"])
    final["drift_half_decay_s"] = half_decay(times, per_step["drift_cm"], per_step["tactile_time_s"])
    final.update(probes(times, per_step["drift_cm"], probe_times))
    return final

