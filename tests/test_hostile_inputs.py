"""Hostile inputs: settings out of their bounds, names too long, checkpoints that are not there, verdicts and
listeners that are not what they claim, and processes that would outlive their command.

A refusal is asserted through the command line where it is the command's (one line on stderr, exit status 2,
no traceback, nothing written: tests.test_hostile_files.rhi and refused), in-process where a function is the
unit. No case trains a decoder.
"""
from __future__ import annotations

import os
import re

import pytest

from tests.test_hostile_files import REPO, refused, rhi, snapshot


def load(overrides: dict, model: str = "paper"):
    from master.experiment import config

    return config.load(overrides=overrides, model_name=model)


# ======================================================================================================
# Every component parameter within its range and the component's rules when the configuration loads
# ======================================================================================================
@pytest.mark.parametrize("key, value, model, says", [
    ("brain.sync_sd", 0.0, "paper", "brain.sync_sd must be positive and finite, got 0.0"),
    ("brain.async_density", 0.0, "paper", "brain.async_density must be positive and finite"),
    ("brain.action_limit", 0.0, "paper", "brain.action_limit must be positive and finite"),
    ("stimulus.period", 0.0, "paper", "stimulus.period = 0.0 is outside its range [0.001, None] s"),
    ("stimulus.ball_distance", -1.0, "paper", "stimulus.ball_distance = -1.0 is outside its range"),
    ("conditions.left", -2.0, "paper", "conditions.left = -2.0 m (rubber_arm.offset_y = 0.0 m) puts the rubber hand "
                                       "out of the arm's reach"),
    ("brain.sync_sd", 0.0, "causal", "brain.sync_sd = 0.0 is outside its range [1e-12, None] s"),
    ("causal.pixel_weight", -1.0, "causal", "causal.pixel_weight: brain.pixel_weight = -1.0 is outside its range"),
])
def test_a_parameter_a_component_would_refuse_is_refused_when_the_configuration_loads(key, value, model, says):
    from master.cosim import ConfigError

    with pytest.raises(ConfigError, match=re.escape(says)):
        load({key: value}, model)


def test_sync_sd_zero_is_refused_by_the_command_before_any_training(tmp_path):
    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "c.toml").write_text('[experiment]\ndecoders = ["conv"]\n[brain]\nsync_sd = 0.0\n')
    before = snapshot(tmp_path)
    done = rhi(tmp_path, "experiment", "--quick", "--config", "c.toml", "--out", "out")
    refused(done, "brain.sync_sd must be positive and finite, got 0.0")
    assert snapshot(tmp_path) == {**before, **{name: ("folder",) for name in ("tmp", "cache")}}  # nothing trained


def test_a_checkpoint_named_for_a_decoder_that_does_not_run_must_exist(tmp_path):
    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "c.toml").write_text('[experiment]\ndecoders = ["conv"]\n')
    done = rhi(tmp_path, "experiment", "--quick", "--config", "c.toml", "--vae-checkpoint", "/nonexistent.pt",
               "--out", "out")
    refused(done, "decoder.vae_checkpoint: /nonexistent.pt does not exist")
    assert sorted(os.listdir(tmp_path / "work")) == ["c.toml"]


# ======================================================================================================
# Bounds on names and settings, each stated in docs/safety.md
# ======================================================================================================
@pytest.mark.parametrize("command", [["experiment", "--quick"], ["train", "--decoder", "conv"], ["sweep", "--config",
                                                                                                   "s.toml"]])
def test_an_output_name_over_the_file_system_s_limit_is_refused_naming_it(tmp_path, command):
    from master.outputs.files import NAME_MARGIN
    from tests.test_sweep import sweep_file

    (tmp_path / "work").mkdir()
    sweep_file(tmp_path / "work" / "s.toml", grid={"conditions.left": [-0.1]})
    limit = os.pathconf(tmp_path / "work", "PC_NAME_MAX")
    name = "a" * 300 + (".pt" if command[0] == "train" else "")
    done = rhi(tmp_path, *command, "--out", name)
    refused(done, f"has {len(name)} bytes, over the limit of {limit - NAME_MARGIN} (this file system's NAME_MAX of "
                  f"{limit}")
    assert sorted(os.listdir(tmp_path / "work")) == ["s.toml"]


@pytest.mark.parametrize("overrides, says", [
    ({"train.threads": 100000}, "train.threads = 100000 must be 0 (every usable core) to 1024"),
    ({"experiment.step_size": 1e300}, "experiment.step_size = 1e+300 s is over the limit of stimulus.period = 2 s"),
    ({"experiment.step_size": 0.2}, "must be below 2 x brain.action_time_constant = 0.2 s"),
    ({"experiment.step_size": 1.0, "brain.action_time_constant": float("inf"), "brain.proprioceptive_variance": 0.5},
     "must be below 2 x brain.proprioceptive_variance = 1 s"),
])
def test_threads_and_the_step_size_are_bounded(overrides, says):
    from master.cosim import ConfigError

    with pytest.raises(ConfigError, match=re.escape(says)):
        load(overrides)
    # just inside each bound: accepted (0.19 s < 2 x 0.1 s; 1024 threads)
    load({"experiment.step_size": 0.19, "train.threads": 1024})


def test_a_huge_step_size_is_one_line_without_numpy_s_warnings(tmp_path):
    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "c.toml").write_text("[experiment]\nstep_size = 1e300\n")
    refused(rhi(tmp_path, "experiment", "--quick", "--config", "c.toml", "--out", "out"), "is over the limit of "
            "stimulus.period")


def test_a_phenomenon_point_out_of_reach_is_refused_before_the_sweep_runs(tmp_path):
    (tmp_path / "work").mkdir()
    shipped = (REPO / "master" / "phenomena" / "distance.toml").read_text()
    (tmp_path / "work" / "far.toml").write_text(shipped.replace("0.40, 0.45]", "0.40, 0.95]"))
    done = rhi(tmp_path, "phenomenon", "distance", "--config", "far.toml", "--out", "out")
    refused(done, "sweep point 8 (conditions.right=0.95): conditions.right = 0.95 m (rubber_arm.offset_y = 0.0 m) puts "
                  "the rubber hand out of the arm's reach")
    assert sorted(os.listdir(tmp_path / "work")) == ["far.toml"]
