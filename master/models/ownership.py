"""The ownership model: ownership as accumulated timing evidence, drift as a slow realignment (docs/model.md).

Its system is a task's with the pose encoder added (the camera's image in, the seen pose into the brain) and
the ownership brain in the paper brain's place; like the causal brain it declares no input for a simulator
position, so the assembly (:func:`rhi.master.tasks.scene.assemble`) leaves out the links that would hand it one.
Its parameters the paper's brain also has come from ``[brain]`` as for the paper (its ownership prior is
``brain.gamma0``, which ownership.toml sets to its own fitted value, its stroke period ``stimulus.period``); the rest
from ``[ownership]`` (master/models/ownership.toml) or derived here.
"""
from __future__ import annotations

import numpy as np

from rhi.master.cosim import ConfigError
from rhi.master.models.base import Model, TrialValues
from rhi.master.models.paper import rest_belief, with_paper_sources

OWN_SOURCES = {
    "brain.ownership_prior": "brain.gamma0",
    "brain.stroke_period": "stimulus.period",
    "brain.coupling_prior": "ownership.coupling_prior",
    "brain.timing_sd": "brain.sync_sd",
    "brain.coupling_window_sd": "ownership.coupling_window_sd",
    "brain.counter_evidence_leak": "ownership.counter_evidence_leak",
    "brain.proprioceptive_fading_rate": "ownership.proprioceptive_fading_rate",
    "brain.peripersonal_sd": "derived: from ownership.peripersonal_boundary and the arm's reach, the spread at "
                             "which a touch seen that far from the felt one is neutral "
                             "(ownership_inference.peripersonal_sd_from_boundary)",
    "brain.upper_arm_length": "derived: the body's upper arm, rhi.components.body.kinematics.UPPER_ARM (the brain's "
                              "body schema is the body's geometry)",
    "brain.forearm_length": "derived: the body's forearm, rhi.components.body.kinematics.FOREARM",
    "brain.realignment_weight": "ownership.realignment_weight",
    "brain.switching_rate": "ownership.switching_rate",
    "brain.realignment_rate": "ownership.realignment_rate",
    "brain.participant_seed": "per trial: the trial's seed (its own stream of perceptual timing noise)",
}
# Why the keys shared with the paper's model are this model's constants too (docs/model.md's table).
SHARED_KEYS = {"stimulus.period": "s, the protocol's stroke period: the asynchrony under two causes is uniform over "
                                  "one period, density 1/T",
               "brain.sync_sd": "s, ownership's visuo-tactile window: the paper's sd of t_v - t_t under one cause (Rood "
                                "et al. 2020, eq. 8, for strokes; the illusion survives delays up to about 300 ms, "
                                "Shimada, Fukuda & Hiraki 2009, PLoS ONE 4:e6185)"}
# The keys derived parameters come from: brain.peripersonal_sd from the boundary.
DERIVED_FROM = {"brain.peripersonal_sd": "ownership.peripersonal_boundary"}
# The free parameters, fitted on the training set: (prior, low, high) each, stated before the fit that uses it
# (docs/model.md, "The ownership model": why these ranges, and why the coupling prior joined the rates). Their
# values in ownership.toml are the adopted joint points (point.csv) of the population fits shipped in FIT_FOLDERS
# (relative to the project; the drift's on Rohde et al. 2011 and Kocur et al. 2022, the onset's on Kalckert &
# Ehrsson 2017), their population medians where they fit a [population]; a parameter no such fit has keeps the
# posterior median of the individual fit in MEDIAN_FIT_FOLDER (fitted_values).
FREE_PARAMETERS = {"ownership.switching_rate": ("log-uniform", 1.0 / 600.0, 1.0),
                   "ownership.realignment_rate": ("log-uniform", 1.0 / 600.0, 1.0),
                   "ownership.coupling_prior": ("uniform", 0.01, 0.99),
                   "ownership.coupling_window_sd": ("log-uniform", 0.1, 10.0),
                   "ownership.counter_evidence_leak": ("log-uniform", 1.0 / 600.0, 1.0),
                   "ownership.proprioceptive_fading_rate": ("log-uniform", 1.0 / 600.0, 1.0),
                   "brain.gamma0": ("log-uniform", 1e-5, 0.5)}  # ownership's prior: the onset fit's only
# Each of FIT_FOLDERS with the rule that chose its point.csv (docs/fit.md: "What ships"; the onset's by the rule of
# rhi.master.fit.point when it ran, since replaced: "Several studies")
FIT_FOLDERS = {"docs/fit/human/ownership_training_screen": "the candidate of least largest miss over the training "
                                                           "statistics (20 studies each; docs/fit.md, \"What ships\")",
               "docs/fit/human/ownership_onset": "the joint posterior mode in the inference space (the rule then; "
                                                 "docs/fit.md, \"Several studies\")"}
MEDIAN_FIT_FOLDER = "docs/fit/human/ownership_rohde2011"


def fitted_values(root) -> dict[str, dict]:
    """Each free parameter's fitted value as shipped: {key: {"value", "q05", "q95", "rule", "folder"}}, from the
    first of FIT_FOLDERS whose point.csv and estimates.csv have it (the key itself, or its population median
    ``population.KEY.median``), else MEDIAN_FIT_FOLDER's estimates.csv (the posterior median); ``root`` the
    project's folder."""
    import csv
    from pathlib import Path

    def rows(folder, name):
        with open(Path(root) / folder / name, encoding="utf-8") as file:
            return {row["parameter"]: row for row in csv.DictReader(file)}

    fits = [(folder, rows(folder, "point.csv"), rows(folder, "estimates.csv")) for folder in FIT_FOLDERS]
    medians = rows(MEDIAN_FIT_FOLDER, "estimates.csv")
    result = {}
    for key in FREE_PARAMETERS:
        fitted = next(((folder, point, estimates, name) for folder, point, estimates in fits
                       for name in (key, f"population.{key}.median") if name in point), None)
        if fitted:
            folder, point, estimates, name = fitted
            result[key] = {"value": float(point[name]["value"]), "q05": float(estimates[name]["q05"]),
                           "q95": float(estimates[name]["q95"]),
                           "rule": FIT_FOLDERS[folder],
                           "folder": folder}
        elif key in medians:
            result[key] = {"value": float(medians[key]["median"]), "q05": float(medians[key]["q05"]),
                           "q95": float(medians[key]["q95"]), "rule": "the posterior median", "folder": MEDIAN_FIT_FOLDER}
    return result


def positive(trials: TrialValues, key: str, unit: str) -> np.ndarray:
    """The values of configuration ``key`` per trial (or one), a ConfigError if one is not positive and finite."""
    values = np.asarray(trials.value(key), dtype=float)
    bad = values[~((values > 0) & np.isfinite(values))]
    if bad.size:
        raise ConfigError(f"{key} must be a positive, finite {unit}, got {float(bad.flat[0])!r}")
    return values


def _brain_class():
    from rhi.components.brain.ownership_brain import OwnershipBrain
    return OwnershipBrain


class OwnershipModel(Model):
    """The ownership brain (:class:`rhi.components.brain.ownership_brain.OwnershipBrain`) with the pose encoder."""

    name = "ownership"
    summary = "the ownership model: ownership from accumulated timing evidence, drift as a slow realignment"
    settings_file = "ownership.toml"
    sees_pose = True
    pose_encoder_key = "ownership.{kind}_pose_encoder"
    pose_encoder_stem = "pose-ownership-{kind}"  # its own, over the rubber arm's whole reach (pose_encoders.py)
    batchable = tuple(DERIVED_FROM.values())
    links = (("camera.image", "pose_encoder.image"), ("pose_encoder.pose", "brain.seen_pose"),
             ("stimulus.arm_visible", "brain.arm_visible"))  # the scene declares whether a rubber arm is in view
    record = ("brain.coupling", "brain.realignment", "brain.ownership_onset")
    measures = {"ownership_onset_s": "brain.ownership_onset", "coupling": "brain.coupling"}

    def brain(self):
        """A new :class:`~rhi.components.brain.ownership_brain.OwnershipBrain`."""
        return _brain_class()()

    @property
    def parameter_sources(self) -> dict:
        """The paper's brain's sources of the parameters the ownership brain also declares, and its own."""
        return with_paper_sources(_brain_class()(), OWN_SOURCES)

    def parameters(self, trials: TrialValues) -> dict:
        """The plain sources' values, and the derived ones: peripersonal_sd per trial, the body schema's lengths,
        the seeds."""
        from rhi.components.body.kinematics import FOREARM, UPPER_ARM
        from rhi.components.brain.ownership_inference import peripersonal_sd_from_boundary

        given = {**super().parameters(trials), "brain.mu0": rest_belief(trials)}
        boundary = positive(trials, DERIVED_FROM["brain.peripersonal_sd"], "distance in m")
        reach = UPPER_ARM + FOREARM
        try:
            given["brain.peripersonal_sd"] = np.vectorize(peripersonal_sd_from_boundary)(boundary, reach)
        except ValueError as error:
            raise ConfigError(f"{DERIVED_FROM['brain.peripersonal_sd']}: {error}") from None
        given["brain.upper_arm_length"], given["brain.forearm_length"] = UPPER_ARM, FOREARM
        given["brain.participant_seed"] = np.asarray(trials.seeds, dtype=np.int64)
        return given

    def trials_per_point(self, config: dict) -> int | None:
        """``ownership.participants``: one simulated participant a trial."""
        return config["ownership"]["participants"]

    def reads_pixels(self, config: dict) -> bool:
        """Never: the seen arm enters only through the pose encoder and the realignment."""
        return False
