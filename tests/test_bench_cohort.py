"""`rhi bench --cohort`: the CPU each component's steps take is attributed to it (a component that burns a known
amount of CPU), and a measured cell reports what it ran."""
import time

import numpy as np
import pytest

from rhi.components.component import Component
from rhi.master.bench import cohort
from rhi.master.commands.bench import run as run_bench
from rhi.master.commands.cli import build_parser
from rhi.master.cosim import ConfigError


class Burner(Component):
    """Burns ``seconds`` of this process's CPU each step (busy, measured by the same clock)."""

    def __init__(self, name, seconds):
        super().__init__(name, [])
        self.seconds = seconds

    def step(self, t, h):
        began = time.process_time()
        while time.process_time() - began < self.seconds:
            pass


def test_each_component_s_cpu_is_its_own():
    slow, quick = Burner("slow", 0.004), Burner("quick", 0.001)
    for part in (slow, quick):
        part.instantiate(1)
        part.enter_initialization_mode()
        part.exit_initialization_mode()
    with cohort.cpu_per_component() as spent:
        for step in range(20):
            slow.do_step(step * 0.02, 0.02)
            quick.do_step(step * 0.02, 0.02)
    # each burned at least its 20 x seconds, and less than that plus the clock's calls, do_step's own work and
    # the busy loop's last turn (a few µs a step: 1 ms in 20 steps is 50 µs a step of room)
    assert 0.080 <= spent["slow"] < 0.081 and 0.020 <= spent["quick"] < 0.021
    assert Component.do_step is not None and "timed" not in Component.do_step.__name__  # put back


def test_a_measured_cell_reports_its_parts_and_its_participant_steps():
    row = cohort.measure("ownership", 4, "batched", 2)
    assert (row["model"], row["batch"], row["body"], row["steps"]) == ("ownership", 4, "batched", 2)
    assert set(row["shares"]) == {"rubber_arm", "stimulus", "camera", "pose_encoder", "brain", "body", "master"}
    assert sum(row["shares"].values()) == pytest.approx(1.0, abs=1e-12)  # the parts and the master make the whole
    assert all(share >= 0 for name, share in row["shares"].items() if name != "master")
    assert np.isfinite(row["us_per_participant_step"]) and row["us_per_participant_step"] > 0


def test_cohort_with_training_or_a_checkpoint_is_refused(tmp_path):
    (tmp_path / "x.pt").write_bytes(b"")
    for extra in (["--training"], ["--checkpoint", str(tmp_path / "x.pt")]):
        with pytest.raises(ConfigError, match="--cohort measures"):
            run_bench(build_parser().parse_args(["bench", "--cohort", *extra]))


def test_a_study_row_sets_a_population_of_distinct_participants_against_as_many_clone_trials():
    from rhi.master import config as configuration
    from rhi.master.bench import study_cost
    from rhi.master.config.protocol import plan
    from rhi.master.models.ownership import FREE_PARAMETERS

    row = study_cost.study_cost("ownership", 2, 2)
    config = configuration.load(model_name="ownership", overrides={"experiment.decoders": ["conv"]})
    cells = len(config["experiment"]["conditions"]) * len(config["experiment"]["stimulations"])
    assert (row["participants"], row["cells"], row["batch"]) == (2, cells, 2 * cells)
    # the ratio is the two batches' CPU, as the row's own columns give it
    assert row["ratio"] == pytest.approx(row["study_cpu_s"] / (row["trial_cpu_s"] * row["batch"]), rel=1e-12)
    assert row["study_decoder_points"] is None  # the ownership model reads no pixel term
    # every free parameter varies within its prior's range, and each participant is one person across the cells
    study = configuration.merge(config, {"population": study_cost.population_of("ownership"), "experiment": {"trials": 3}})
    drawn = [dict(t.overrides) for t in plan(study)]
    for key, (_, low, high) in FREE_PARAMETERS.items():
        values = {d[key] for d in drawn}
        assert len(values) == 3 and all(low <= v <= high for v in values), key


def test_an_exact_study_row_runs_the_decoder_without_its_fast_mode(monkeypatch):
    """The exact row's two batches both run the decoder exact (no linearisation shared between trials)."""
    from rhi.master.bench import study_cost

    seen = []
    real = study_cost.batch_cpu

    def noting_the_mode(config, checkpoint, with_population):
        seen.append(config["decoder"]["fast"])
        return real(config, checkpoint, with_population)

    monkeypatch.setattr(study_cost, "batch_cpu", noting_the_mode)
    row = study_cost.study_cost("paper", 2, 2, exact=True)
    assert row["exact"] and seen and not any(seen)
    assert row["study_decoder_points"] is None and row["clone_decoder_points"] is None  # nothing linearised
    monkeypatch.setattr(study_cost, "study_cost", lambda model, n, steps, exact=False: (model, n, exact))
    assert study_cost.study_rows(3, quick=True)[-1] == ("paper", study_cost.QUICK_STUDY_SIZES[0], True)


def test_a_cohort_report_names_its_machine_and_prints_its_study_rows(monkeypatch):
    from rhi.master.bench import study_cost

    monkeypatch.setattr(cohort, "measure", lambda model, batch, body, steps: {
        "model": model, "batch": batch, "body": body, "steps": steps, "us_per_participant_step": 1.0,
        "first_batch_us": 2.0, "shares": {"body": 1.0}})
    monkeypatch.setattr(study_cost, "study_rows", lambda steps, quick: [{
        "model": "paper", "participants": 2, "cells": 6, "batch": 12, "steps": 4, "study_cpu_s": 0.3,
        "trial_cpu_s": 0.02, "ratio": 1.25, "study_decoder_points": 9, "clone_decoder_points": 6}])
    report = cohort.cohort_report(quick=True, model_names=["paper"])
    text = cohort.cohort_table(report)
    assert report["machine"]["cpu"] and text.startswith(f"machine: {report['machine']['cpu']}")
    # 0.02 s x 12 trials = 0.240 s of clones against the study's 0.300 s
    assert "paper           2     6     12     0.300        0.240  1.250  9, 6" in text
