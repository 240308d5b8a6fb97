"""Hostile limits: a file of the wrong kind where a checkpoint belongs, settings whose size or number implies more
memory or work than any machine has, values that are not numbers where numbers belong, and settings read from one
file but not from another.

Each case runs the real command line (tests.faults.rhi: in this process, or a subprocess where noted; cwd the case's
own ``work``, TMPDIR and RHI_CACHE inside its tree) where the refusal is the command's, and checks what rhi guarantees
(docs/configuration.md, "What rhi refuses, and what it guarantees"; docs/safety.md): one line on stderr and exit
status 2 for a refusal, before any work, no traceback, nothing written. No case trains a default decoder.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests.faults import refused, rhi
from tests.test_hostile_folders import changed_outside, prepared, tree


# ======================================================================================================
# 4b. A FIFO or a device where a checkpoint belongs is refused by its kind, before it is opened
# ======================================================================================================
def hostile_file(work: Path, kind: str) -> str:
    if kind == "device":
        return "/dev/zero"
    os.mkfifo(work / "pipe.pt")  # nothing ever writes it: opening it for reading would wait forever
    return "pipe.pt"


@pytest.mark.parametrize("kind", ["fifo", "device"])
@pytest.mark.parametrize("command", ["experiment", "bench", "export-agent"])
def test_a_checkpoint_that_is_a_fifo_or_a_device_is_refused_by_its_kind(tmp_path, kind, command):
    work = prepared(tmp_path)
    path = hostile_file(work, kind)
    arguments = {"experiment": ["experiment", "--quick", "--conv-checkpoint", path, "--out", "out"],
                 "bench": ["bench", "--quick", "--checkpoint", path],
                 "export-agent": ["export-agent", "--decoder", "conv", "--checkpoint", path, "--out", "a.fmu"]}[command]
    before = tree(tmp_path)
    says = f"--checkpoint {path}" if command == "bench" else f"decoder.conv_checkpoint: {path}"
    # own process: opening the FIFO would wait forever, reading the device would never end
    refused(rhi(tmp_path, *arguments, timeout=30, own_process=True),
            f"{says} is not a regular file (a FIFO, a device or a socket)")
    assert changed_outside(before, tree(tmp_path), "\0") == []


@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_a_checkpoint_loaded_directly_that_is_a_fifo_or_a_device_is_refused_without_opening_it(tmp_path, kind):
    import signal

    from rhi.components.vision import checkpoint

    def hung(*_):
        raise TimeoutError("checkpoint.load opened the FIFO and waited for a writer")

    path = hostile_file(tmp_path, kind)
    previous = signal.signal(signal.SIGALRM, hung)
    signal.alarm(10)
    try:
        with pytest.raises(checkpoint.CheckpointError, match="is not a regular file"):
            checkpoint.load(tmp_path / path if kind == "fifo" else path)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


# ======================================================================================================
# 16. A checkpoint whose metadata JSON nests 100 000 deep is refused in one line
# ======================================================================================================
def test_a_checkpoint_whose_metadata_nests_deep_is_refused_in_one_line(tmp_path):
    import torch

    from rhi.components.vision.checkpoint import FORMAT
    from tests.test_hostile_folders import DEEP

    work = prepared(tmp_path)
    torch.save({"format": FORMAT, "metadata": DEEP, "weights": {}}, work / "deep.pt")
    before = tree(tmp_path)
    refused(rhi(tmp_path, "experiment", "--quick", "--conv-checkpoint", "deep.pt", "--out", "out", timeout=30),
            "deep.pt: its metadata nests over")
    assert changed_outside(before, tree(tmp_path), "\0") == []


# ======================================================================================================
# 6. A reach whose goals imply more memory than any machine has is refused before any work
# ======================================================================================================
@pytest.mark.parametrize("goals", [10**9, 2**63])
def test_a_reach_with_too_many_goals_is_refused_with_the_memory_it_implies(tmp_path, goals):
    prepared(tmp_path)
    before = tree(tmp_path)
    # own process: were the bound not applied, the allocation would take the test's process down
    done = rhi(tmp_path, "reach", "--quick", "--goals", goals, "--out", "out", timeout=30, own_process=True)
    refused(done, "this reach would need about ")
    assert f"({goals} goals x 1 bands x 2 decoders of 500 steps at 32 x 32 px), more than this machine's" in done.stderr
    assert "lower reach.goals (--goals)" in done.stderr
    assert changed_outside(before, tree(tmp_path), "\0") == []  # nothing trained, nothing written


def test_the_reach_memory_bound_counts_every_reach_and_lets_the_shipped_reach_run():
    from rhi.master.config import BYTES_PER_BATCH_PIXEL, BYTES_PER_TRIAL_STEP, physical_memory
    from rhi.master.tasks.reach import task as reach

    config = reach.load(quick=True, overrides={"reach.goals": 7})
    # 7 goals x 1 band x 2 decoders, 501 recorded steps, two cameras' 32 x 32 images each
    assert reach.memory_needed(config) == 14 * 501 * BYTES_PER_TRIAL_STEP + 2 * 14 * 32 * 32 * BYTES_PER_BATCH_PIXEL
    shipped = reach.load()  # the released agent's 40 goals x 2 bands x 2 decoders of 5000 steps: well inside
    assert reach.memory_needed(shipped) < min(physical_memory() or 2**40, 8 * 2**30)


# ======================================================================================================
# 7. sweep.workers and fit.workers are bounded: four local worker processes per usable core
# ======================================================================================================
def cores() -> int:
    return len(os.sched_getaffinity(0))


@pytest.mark.parametrize("command", ["sweep", "fit"])
def test_a_worker_count_over_four_per_core_is_refused_before_any_work(tmp_path, command):
    from tests.sweep_files import sweep_file
    from tests.test_hostile_folders import DATA, FIT

    work = prepared(tmp_path)
    if command == "sweep":
        sweep_file(work / "s.toml", grid={"conditions.left": [-0.1]}, trials=1, conditions=("left",), workers=100000)
        arguments = ["sweep", "--config", "s.toml", "--out", "out"]
    else:
        (work / "fit.toml").write_text(FIT.format(checkpoint="").replace("workers = 1\n", "workers = 100000\n"))
        (work / "data.csv").write_text(DATA)
        arguments = ["fit", "--data", "data.csv", "--config", "fit.toml", "--out", "out"]
    before = tree(tmp_path)
    refused(rhi(tmp_path, *arguments, timeout=30),
            f"{command}.workers = 100000 is over the limit of {4 * cores()} (4 x this machine's {cores()} usable cores)")
    assert changed_outside(before, tree(tmp_path), "\0") == []


def test_a_worker_count_of_four_per_core_is_accepted_and_one_more_is_not(tmp_path):
    from rhi.master.sweeps import plan as sweeps
    from tests.sweep_files import sweep_file

    path = sweep_file(tmp_path / "s.toml", grid={"conditions.left": [-0.1]}, trials=1, workers=4 * cores())
    assert sweeps.load(path).workers == 4 * cores()
    sweep_file(path, grid={"conditions.left": [-0.1]}, trials=1, workers=4 * cores() + 1)
    with pytest.raises(Exception, match="is over the limit"):
        sweeps.load(path)


# ======================================================================================================
# 8-9. Every fit.estimator key: its type, its range and the memory it implies, before any simulation
# ======================================================================================================
def with_lines(text: str, table: str, changes: str) -> str:
    """``text`` with the ``key = value`` lines of ``changes`` in ``table``, in place of its lines of those keys."""
    lines, changes = text.splitlines(), changes.splitlines()
    start = lines.index(table) + 1
    end = next((i for i in range(start, len(lines)) if lines[i].startswith("[")), len(lines))
    keys = {change.split("=")[0].strip() for change in changes}
    kept = [line for line in lines[start:end] if line.split("=")[0].strip() not in keys]
    return "\n".join(lines[:start] + kept + changes + lines[end:]) + "\n"


def fit_files(work: Path, estimator: str = "", fit: str = "", checkpoint: str = "", data: str | None = None):
    """work/fit.toml (tests.test_hostile_folders.FIT with the lines ``estimator`` in [fit.estimator] and ``fit`` in
    [fit]) and work/data.csv (its DATA, or ``data``); returns both paths."""
    from tests.test_hostile_folders import DATA, FIT

    text = with_lines(with_lines(FIT.format(checkpoint=checkpoint), "[fit.estimator]", estimator), "[fit]", fit)
    (work / "fit.toml").write_text(text)
    (work / "data.csv").write_text(DATA if data is None else data)
    return work / "fit.toml", work / "data.csv"


def read_fit(work: Path, **changes):
    from rhi.master.fit.data import read_data
    from rhi.master.fit.plan import read_plan

    plan_path, data_path = fit_files(work, **changes)
    return read_plan(str(plan_path), read_data(data_path))


@pytest.mark.parametrize("line, says", [
    ("hidden_features = 1000000000", "fit.estimator.hidden_features = 1000000000 is over the limit of 1024 (about "
                                     "twenty times sbi's 50"),
    ("transforms = 1000000", "fit.estimator.transforms = 1000000 is over the limit of 64 (about thirteen times sbi's 5"),
    ("threads = 100000", "fit.estimator.threads = 100000 is over the limit of 1024 (twice the hardware threads"),
    ("ensemble = 1000", "fit.estimator.ensemble = 1000 is over the limit of 32"),
    ("max_epochs = 1000000000", "fit.estimator.max_epochs = 1000000000 is over the limit of 100000"),
    ("batch_size = 1000000", "fit.estimator.batch_size = 1000000 is over the limit of 100000"),
    ("learning_rate = 1e30", "fit.estimator.learning_rate = 1e+30 is over the limit of 1 (a step that moves each "
                             "weight by more than its initial scale"),
    ("learning_rate = inf", "fit.estimator.learning_rate = inf must be a positive finite number"),
    ("learning_rate = nan", "fit.estimator.learning_rate = nan must be a positive finite number"),
    ("transforms = 1e6", "fit.estimator.transforms = 1000000.0 must be a positive whole number"),
    ("hidden_features = 0", "fit.estimator.hidden_features = 0 must be a positive whole number"),
    ("density = 'x'", "fit.estimator.density = 'x' is not one of maf, nsf, mdn"),
])
def test_an_estimator_key_out_of_its_range_is_refused_when_the_fit_file_is_read(tmp_path, line, says):
    import re

    from rhi.master.cosim import ConfigError

    with pytest.raises(ConfigError, match=re.escape(says)):
        read_fit(tmp_path, estimator=line)


def test_each_estimator_key_at_its_limit_is_accepted(tmp_path, monkeypatch):
    from rhi.master import config as configuration

    monkeypatch.setattr(configuration, "physical_memory", lambda: 0)  # unknown: the memory is not checked
    plan = read_fit(tmp_path, estimator="hidden_features = 1024\ntransforms = 64\nthreads = 1024\nensemble = 32\n"
                                        "max_epochs = 100000\nbatch_size = 100000\nlearning_rate = 1.0")
    assert plan.estimator["hidden_features"] == 1024 and plan.estimator["learning_rate"] == 1.0


def test_an_estimator_that_needs_more_memory_than_the_machine_has_is_refused_saying_how_much(tmp_path, monkeypatch):
    from rhi.master import config as configuration
    from rhi.master.cosim import ConfigError

    monkeypatch.setattr(configuration, "physical_memory", lambda: 2 * 2**30)  # a machine of 2 GiB
    # 1 parameter, 1 statistic (drift_cm in left/sync): 8 x 64 transforms x 1024 x (1024 + 3) weights of 16 bytes,
    # and 200 rows x 64 x 1024 x 128 bytes of activations: 8.03 GiB + 1.56 GiB
    needed = 8 * 64 * 1024 * 1027 * 16 + 200 * 64 * 1024 * 128
    with pytest.raises(ConfigError) as refusal:
        read_fit(tmp_path, estimator="hidden_features = 1024\ntransforms = 64\nbatch_size = 200")
    assert str(refusal.value) == (
        f"training the estimator would need about {needed / 2**30:.1f} GiB of memory (1 x a maf of 64 transforms of "
        "1024 hidden features, batches of 200), more than this machine's 2.0 GiB; lower fit.estimator.hidden_features, "
        "transforms, ensemble or batch_size")
    read_fit(tmp_path, estimator="hidden_features = 50\ntransforms = 5\nbatch_size = 200")  # sbi's size: about 11 MiB


def test_fit_estimator_threads_over_the_limit_is_refused_by_the_command_before_any_simulation(tmp_path):
    from rhi.components.body.kinematics import REST_POSE
    from rhi.master.decoders.training_data import HALF_RANGES
    from tests.faults import tiny_checkpoint

    work = prepared(tmp_path)
    checkpoint = tiny_checkpoint(work / "tiny.pt", rest_pose=list(REST_POSE), half_ranges=list(HALF_RANGES))
    fit_files(work, estimator="threads = 100000", checkpoint=str(checkpoint))
    before = tree(tmp_path)
    # own process: were the bound not applied, 100 000 torch threads would be started in the test's process
    refused(rhi(tmp_path, "fit", "--data", "data.csv", "--config", "fit.toml", "--out", "out", timeout=60,
                own_process=True), "fit.estimator.threads = 100000 is over the limit of 1024")
    assert changed_outside(before, tree(tmp_path), "\0") == []


# ======================================================================================================
# 10. A loss that becomes NaN while the estimator trains: one line, exit status 1 (a failure during the work)
# ======================================================================================================
def test_a_loss_that_becomes_nan_in_training_is_one_line_and_exit_status_1(tmp_path, monkeypatch):
    from rhi.master.fit import estimator_settings
    import tests.test_hostile_folders as folders

    # the bound that refuses learning_rate = 1e30 before any work, lifted: here, where rhi runs (in this process)
    monkeypatch.setattr(estimator_settings, "MAX_LEARNING_RATE", float("inf"))
    monkeypatch.setattr(folders, "FIT", folders.FIT.replace("threads = 1\n", "threads = 1\nlearning_rate = 1e30\n"))
    work = prepared(tmp_path)
    out = folders.fit_folder(work)  # every simulation made up: the fit goes straight to the training
    before = tree(tmp_path)
    done = rhi(tmp_path, "fit", "--data", "data.csv", "--config", "fit.toml", "--out", "out", timeout=120)
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert done.stderr.strip().splitlines()[-1] == (
        "rhi fit: error: training the estimator failed: its loss became NaN or infinite (fit.estimator.learning_rate "
        "= 1e+30, batch_size = 10); lower fit.estimator.learning_rate. The simulations are kept: the same command "
        "resumes")
    after = tree(tmp_path)
    assert changed_outside(before, after, "work/out") == []
    changed = {name for name in set(before) | set(after) if before.get(name) != after.get(name)
               and name.startswith("work/")}
    assert all(name.startswith("work/out/simulations/") for name in changed), changed  # its tables, rewritten
    assert not (out / "estimator.pt").exists() and not (out / "posterior.csv").exists()


# ======================================================================================================
# 5, 11. An estimator.pt of this very training set whose weights are NaN or of other shapes is trained again
# ======================================================================================================
@pytest.mark.parametrize("damage", ["nan", "shapes"])
def test_a_saved_estimator_with_nan_or_misshapen_weights_is_trained_again_with_a_note(tmp_path, damage, capsys):
    import signal

    import numpy as np
    import torch

    from rhi.master.runtime.logs import configured
    from rhi.master.fit import inference
    from rhi.master.fit.run import load_or_train

    plan = read_fit(tmp_path)
    generator = np.random.default_rng(0)
    theta = generator.uniform(np.log(5.0), np.log(80.0), (20, 1))
    x = theta + generator.normal(0.0, 0.1, (20, 1))
    path = tmp_path / "estimator.pt"
    first, _ = load_or_train(plan, theta, x, path, "a fit")
    shapes = {name: tuple(tensor.shape) for name, tensor in first[0].state_dict().items()}
    saved = torch.load(path, weights_only=True)
    name = next(name for name, tensor in saved["states"][0].items() if tensor.is_floating_point() and tensor.ndim == 2)
    weight = saved["states"][0][name]
    saved["states"][0][name] = (torch.full_like(weight, float("nan")) if damage == "nan"
                                else torch.zeros(weight.shape[0] + 1, weight.shape[1]))
    torch.save(saved, path)
    capsys.readouterr()
    with configured(0):  # the note logged on stderr, as the command line sets it up
        again, _ = load_or_train(plan, theta, x, path, "a fit")
    note = capsys.readouterr().err.strip().splitlines()
    assert len(note) == 1 and note[0].startswith(f"rhi fit: note: {path} does not hold a usable estimator (its weight")
    assert note[0].endswith("; training it again")
    for states in (again[0].state_dict(), torch.load(path, weights_only=True)["states"][0]):  # in use and saved
        assert {key: tuple(value.shape) for key, value in states.items()} == shapes
        assert all(bool(value.isfinite().all()) for value in states.values() if value.is_floating_point())

    def hung(*_):
        raise TimeoutError("sampling the posterior did not end")

    previous = signal.signal(signal.SIGALRM, hung)
    signal.alarm(20)
    try:
        drawn = inference.sample(inference.posterior(plan.parameters, again, plan.estimator, x), x[0], 5, 0)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    assert drawn.shape == (5, 1) and np.isfinite(drawn).all()


# ======================================================================================================
# 13-15, 19. The moving hand's delays and the reach-after's target, precision and release, checked before any work
# ======================================================================================================
@pytest.mark.parametrize("name, table, line, says", [
    ("moving-hand", "moving_hand", "delays = [0, inf]", "config key moving_hand.delays = [0, inf] must be a list of "
                                                        "finite numbers"),
    ("moving-hand", "moving_hand", 'delays = ["x"]', "config key moving_hand.delays = ['x'] must be a list of finite "
                                                     "numbers"),
    ("moving-hand", "moving_hand", "delays = [[0.1]]", "config key moving_hand.delays = [[0.1]] must be a list of "
                                                       "finite numbers"),
    ("reach-after", "reach_after", 'target = ["a", 0.0]', "config key reach_after.target = ['a', 0.0] must be a list "
                                                          "of finite numbers"),
    ("reach-after", "reach_after", "target = [5.0, 5.0]", "reach_after.target = [5.0, 5.0]: hand position"),
    ("reach-after", "reach_after", "precision_ratio = 0.0", "reach_after.precision_ratio must be positive, got 0.0"),
    ("reach-after", "reach_after", "release = 1e12", "reach_after.release + reach_after.window = 1e+12 s is "
                                                     "50000000000750 steps of 0.02 s: this run would need about "),
])
def test_a_phenomenon_protocol_s_bad_value_is_refused_in_one_line_before_any_work(tmp_path, name, table, line, says):
    work = prepared(tmp_path)
    (work / "c.toml").write_text(f"[{table}]\n{line}\n")
    before = tree(tmp_path)
    # the release of 1e12 s in its own process: were the bound not applied, its allocation would take the test's down
    done = rhi(tmp_path, "phenomenon", name, "--config", "c.toml", "--model", "paper", "--out", "out", timeout=30,
               own_process=line == "release = 1e12")
    refused(done, says)
    if line == "release = 1e12":
        assert "lower reach_after.release or reach_after.window" in done.stderr
    assert changed_outside(before, tree(tmp_path), "\0") == []  # nothing trained, nothing written


def test_a_number_list_accepts_whole_and_decimal_numbers_and_refuses_anything_else():
    import math

    from rhi.master import config as configuration
    from rhi.master.cosim import ConfigError

    assert configuration.check_type("k", [0, 0.5, -2], [0.0, 1.0]) == [0, 0.5, -2]
    for value in ([math.nan], [math.inf], [-math.inf], [True], [None], [2**64], [[1.0]], ["1"]):
        with pytest.raises(ConfigError, match="must be a list of finite numbers"):
            configuration.check_type("k", value, [0.0, 1.0])
    assert configuration.check_type("k", ["a"], ["x"]) == ["a"]  # a list of names stays one


# ======================================================================================================
# 17-18. fit.simulations over its limit says so; an observation noise over its limit is refused before any work
# ======================================================================================================
@pytest.mark.parametrize("fit, says", [
    ("simulations = 1000000000", "fit.simulations = 1000000000 is over the limit of 100000 (the most simulated "
                                 "participants a fit runs"),
    ("simulations = 100001", "fit.simulations = 100001 is over the limit of 100000"),
    ("posterior_samples = 1000000000", "fit.posterior_samples = 1000000000 is over the limit of 1000000"),
    ("[fit.noise]\ndrift_cm = 1e308", "fit.noise.drift_cm = 1e+308 is over the limit of 1000 (in the measure's unit"),
    ("[fit.noise]\ndrift_cm = 1000.5", "fit.noise.drift_cm = 1000.5 is over the limit of 1000"),
])
def test_a_fit_setting_over_its_limit_is_refused_saying_so_before_any_simulation(tmp_path, fit, says):
    from rhi.components.body.kinematics import REST_POSE
    from rhi.master.decoders.training_data import HALF_RANGES
    from tests.faults import tiny_checkpoint

    work = prepared(tmp_path)
    checkpoint = tiny_checkpoint(work / "tiny.pt", rest_pose=list(REST_POSE), half_ranges=list(HALF_RANGES))
    if fit.startswith("[fit.noise]"):
        fit_files(work, checkpoint=str(checkpoint))
        (work / "fit.toml").write_text((work / "fit.toml").read_text() + fit + "\n")
    else:
        fit_files(work, fit=fit, checkpoint=str(checkpoint))
    before = tree(tmp_path)
    refused(rhi(tmp_path, "fit", "--data", "data.csv", "--config", "fit.toml", "--out", "out", timeout=60), says)
    assert changed_outside(before, tree(tmp_path), "\0") == []  # no simulation written


def test_a_fit_at_its_limits_is_read(tmp_path):
    plan = read_fit(tmp_path, fit="simulations = 100000\ncalibration = 0\n[fit.noise]\ndrift_cm = 1000.0")
    assert plan.settings["simulations"] == 100000 and plan.noise["drift_cm"] == 1000.0


# ======================================================================================================
# 21. A goal precision ratio that would put the goal image's variance below the decoder's range, in words, at once
# ======================================================================================================
@pytest.mark.parametrize("command", ["reach", "reach-after"])
def test_a_precision_ratio_too_large_for_the_decoder_is_refused_in_words_before_any_training(tmp_path, command):
    work = prepared(tmp_path)
    table = "reach" if command == "reach" else "reach_after"
    (work / "c.toml").write_text(f"[{table}]\nprecision_ratio = 1e300\n")
    arguments = (["reach", "--quick"] if command == "reach" else ["phenomenon", "reach-after", "--model", "paper"])
    before = tree(tmp_path)
    # decoder.visual_variance = 20 (master/config/defaults.toml); the decoder's visual_variance is at least 1e-12
    refused(rhi(tmp_path, *arguments, "--config", "c.toml", "--out", "out", timeout=30),
            f"{table}.precision_ratio = 1e+300 is too large: the goal image's visual variance, decoder.visual_variance "
            f"/ {table}.precision_ratio = 20 / 1e+300 = 2e-299, would be below the decoder's smallest, 1e-12; use at "
            "most 2e+13")
    assert changed_outside(before, tree(tmp_path), "\0") == []  # nothing trained


def test_the_largest_precision_ratio_the_decoder_allows_is_accepted():
    from rhi.master.tasks.reach import task as reach

    assert reach.load(quick=True, overrides={"reach.precision_ratio": 2e13})["reach"]["precision_ratio"] == 2e13


# ======================================================================================================
# 33. A prior whose support leaves the range the parameter's component declares is refused, naming both
# ======================================================================================================
UNBOUNDED_NORMAL = '[fit.parameters.brain.proprioceptive_variance]\nprior = "normal"\nmean = 1.0\nsd = 1.0\n'


@pytest.mark.parametrize("spec, model, says", [
    (UNBOUNDED_NORMAL, "paper", "the normal prior's support [-inf, inf] leaves brain.proprioceptive_variance's range "
                                "[0, inf] deg2: give low within that range"),
    (UNBOUNDED_NORMAL, "causal", "the normal prior's support [-inf, inf] leaves brain.proprioceptive_variance's range "
                                 "[0, inf] deg2: give low within that range"),
    ('[fit.parameters.brain.gamma0]\nprior = "normal"\nmean = 0.5\nsd = 0.1\nlow = 0.01\n', "paper",
     "the normal prior's support [0.01, inf] leaves brain.gamma0's range [0, 1] 1: give high within that range"),
    ('[fit.parameters.brain.sync_sd]\nprior = "uniform"\nlow = -0.1\nhigh = 0.5\n', "paper",
     "the uniform prior's support [-0.1, 0.5] leaves brain.sync_sd's range [0, inf] s: give low within that range"),
])
def test_a_prior_whose_support_leaves_the_parameter_s_range_is_refused_naming_both(tmp_path, spec, model, says):
    """The ranges are the components' own (components/brain/base.py declares proprioceptive_variance >= 0 for every
    brain, its check refusing 0 at initialization; integrator.py gamma0 in [0, 1], sync_sd >= 0)."""
    from rhi.components.brain.causal_brain import CausalBrain
    from rhi.components.brain.integrator import Brain

    brain = (Brain if model == "paper" else CausalBrain)()
    name = spec.split("]")[0].rpartition(".")[2]
    declared = brain.variables[name]
    assert f"[{declared.min:g}, {'inf' if declared.max is None else f'{declared.max:g}'}] {declared.unit}" in says
    work = prepared(tmp_path)
    fit_files(work, fit=f'model = "{model}"')
    text = (work / "fit.toml").read_text()
    (work / "fit.toml").write_text(text.split('[fit.parameters."decoder.visual_variance"]')[0] + spec)
    before = tree(tmp_path)
    refused(rhi(tmp_path, "fit", "--data", "data.csv", "--config", "fit.toml", "--out", "out", timeout=30),
            f"fit.parameters.brain.{name}: {says}")
    assert changed_outside(before, tree(tmp_path), "\0") == []


def test_a_normal_prior_truncated_inside_the_range_is_read(tmp_path):
    work = prepared(tmp_path)
    fit_files(work)
    text = (work / "fit.toml").read_text()
    (work / "fit.toml").write_text(text.split('[fit.parameters."decoder.visual_variance"]')[0] + UNBOUNDED_NORMAL
                                   + "low = 0.1\n")
    from rhi.master.fit.data import read_data
    from rhi.master.fit.plan import read_plan

    (parameter,) = read_plan(str(work / "fit.toml"), read_data(work / "data.csv")).parameters
    assert (parameter.key, parameter.low, parameter.high) == ("brain.proprioceptive_variance", 0.1, float("inf"))


# ======================================================================================================
# 34. [causal] participants in a phenomenon's --config file sets the causal model's trials per point
# ======================================================================================================
class Planned(Exception):
    """Raised by the stand-in for sweep_and_report: the phenomenon was planned, and nothing is run."""


@pytest.mark.parametrize("participants", [1, 3, None])
def test_the_causal_participants_of_a_phenomenon_s_config_file_count(tmp_path, monkeypatch, participants):
    import argparse

    from rhi.master.commands import sweep as sweep_command
    from rhi.master.commands.phenomenon import run as run_phenomenon
    from rhi.master.sweeps import plan
    from tests.faults import REPO

    shipped = (REPO / "master" / "phenomena" / "distance.toml").read_text()
    path = tmp_path / "distance.toml"
    path.write_text(shipped + ("" if participants is None else f"\n[causal]\nparticipants = {participants}\n"))
    given = {}

    def sweep_and_report(path, out, context, model=None, trials=None):
        given.update(trials=trials)
        raise Planned

    monkeypatch.setattr(sweep_command, "sweep_and_report", sweep_and_report)
    with pytest.raises(Planned):
        run_phenomenon(argparse.Namespace(name="distance", config=str(path), scheduler=None, out=str(tmp_path / "out"),
                                          force=False, model="causal", debug=False))
    expected = 10 if participants is None else participants  # master/models/causal.toml: participants = 10
    assert given["trials"] == expected
    sweep = plan.load(path, "causal", given["trials"])  # as the sweep plans it: that many trials at each point
    assert {sum(1 for t in sweep.trials if t.point == p and t.decoder == "conv") for p in range(9)} == {expected}


# ======================================================================================================
# 35. A participant (or a cell's) name in a data file is one line of printable text
# ======================================================================================================
@pytest.mark.parametrize("row, says", [
    ('"two\nlines",left,sync,-0.3\n', "data.csv line 2: column participant = 'two\\nlines' holds a character that is "
                                      "not printable"),
    ('"tab\there",left,sync,-0.3\n', "data.csv line 2: column participant = 'tab\\there' holds a character"),
    ('p1,left,"sy\rnc",-0.3\n', "data.csv line 2: column stimulation = 'sy\\rnc' holds a character"),
    ('p1,left,sync,-0.3\n"bell\x07",left,sync,-0.2\n', "data.csv line 3: column participant = 'bell\\x07' holds"),
])
def test_a_name_that_is_not_one_line_of_printable_text_is_refused_naming_its_line(tmp_path, row, says):
    work = prepared(tmp_path)
    fit_files(work, data="participant,condition,stimulation,drift_cm\n" + row)
    before = tree(tmp_path)
    refused(rhi(tmp_path, "fit", "--data", "data.csv", "--config", "fit.toml", "--out", "out", timeout=30), says)
    assert changed_outside(before, tree(tmp_path), "\0") == []


def test_quoted_names_and_line_numbers_after_a_comment_are_read_as_written(tmp_path):
    from rhi.master.fit.data import read_data

    path = tmp_path / "data.csv"
    path.write_text('# a study\nparticipant,condition,stimulation,drift_cm\n"twolines",left,sync,-0.3\n'
                    '"two, lines",left,sync,-0.1\n\n"Zoë",left,sync,x\n')
    from rhi.master.cosim import ConfigError

    with pytest.raises(ConfigError, match="data.csv line 6: column drift_cm = 'x' is not a number"):
        read_data(path)
    path.write_text(path.read_text().replace(",x\n", ",0.2\n"))
    assert read_data(path).participants == ["twolines", "two, lines", "Zoë"]


# ======================================================================================================
# 36. A trial record whose drift is not a number: refused when read back, a failed trial when a task returns it
# ======================================================================================================
def test_a_planted_trial_record_with_a_drift_in_words_is_refused_naming_it(tmp_path):
    """(refused already by the record check of master/sweeps/folder.py; this case holds it)"""
    import json

    from tests.sweep_files import one_trial_sweep_folder

    work = prepared(tmp_path)
    _, record = one_trial_sweep_folder(work)
    record.write_text(json.dumps({"status": "ok", "outcome": {"drift_cm": "lots", "force_n": 0.0, "gamma_final": 0.1}}))
    before = tree(tmp_path)
    refused(rhi(tmp_path, "sweep", "--config", "s.toml", "--out", "out", timeout=30),
            f"trial record out/trials/{record.name} is not one rhi wrote (its outcome's drift_cm is not a number)")
    assert changed_outside(before, tree(tmp_path), "\0") == []


def test_a_task_whose_drift_is_in_words_fails_its_trial_and_the_tables_keep_their_columns(tmp_path):
    import csv
    import json

    from tests.sweep_files import sweep_file

    work = prepared(tmp_path)
    sweep_file(work / "s.toml", grid={"conditions.right": [0.1]}, task="wordy_outcome", trials=1, workers=1)
    done = rhi(tmp_path, "sweep", "--config", "s.toml", "--out", "out", timeout=120)
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr[-2000:]  # a trial failed
    records = [json.loads(path.read_text()) for path in sorted((work / "out" / "trials").glob("*.json"))]
    failed = [r for r in records if r["status"] == "failed"]
    assert len(records) == 2 and len(failed) == 1  # the right hand's trial; the left hand's is a number
    assert failed[0]["error"] == ("TypeError: the task's outcome is not one a sweep can table: its outcome's drift_cm "
                                  "is not a number")
    with open(work / "out" / "summary.csv") as file:
        header = next(csv.reader(file))
    assert any(column.startswith("drift_cm") for column in header), header


# ======================================================================================================
# 37. rhi bench --quick --checkpoint CKPT measures the drift error on CKPT; with --training it is refused
# ======================================================================================================
def conv_checkpoint_at(path: Path, resolution: int) -> Path:
    """An untrained tiny conv decoder at ``resolution`` px, with the body's rest pose and ranges."""
    from rhi.components.body.kinematics import REST_POSE
    from rhi.components.vision import checkpoint
    from rhi.components.vision.networks import build, preset, sizes_dict
    from rhi.master.decoders.training_data import HALF_RANGES

    metadata = {"kind": "conv", "preset": "tiny", "sizes": sizes_dict(preset("tiny")), "resolution": resolution,
                "rest_pose": list(REST_POSE), "half_ranges": list(HALF_RANGES), "data_hash": "x", "validation_mse": 0.1}
    with open(path, "wb") as file:
        checkpoint.write(file, build("conv", "tiny", resolution), metadata)
    return path


def test_bench_quick_measures_the_drift_error_on_the_checkpoint_given(tmp_path, monkeypatch):
    import argparse

    import rhi.master.commands.bench as bench
    from rhi.master import config as configuration
    from rhi.master.bench.protocol import fast_error

    path = str(conv_checkpoint_at(tmp_path / "conv64.pt", configuration.load()["experiment"]["resolution"]))
    given = []
    monkeypatch.setattr("rhi.master.bench.suite.run_suite", lambda settings: given.append(settings) or {})
    monkeypatch.setattr("rhi.master.bench.report.table", lambda report: "")
    bench.run(argparse.Namespace(quick=True, checkpoint=path, threads=1, json=False, training=False))
    (settings,) = given
    assert (settings.error_checkpoint, settings.error_model, settings.error_steps) == (path, "cached", 30)  # --quick's
    measured = fast_error(settings)
    assert measured["decoder"] == path and measured["steps"] == 30 and measured["trials"] == 6


@pytest.mark.parametrize("case", ["training", "resolution"])
def test_bench_refuses_a_checkpoint_it_would_not_use_before_measuring_anything(tmp_path, case):
    work = prepared(tmp_path)
    conv_checkpoint_at(work / "c.pt", 64 if case == "training" else 32)
    before = tree(tmp_path)
    done = rhi(tmp_path, "bench", "--quick", "--checkpoint", "c.pt", *(["--training"] if case == "training" else []),
               timeout=60)
    refused(done, "--checkpoint names the decoder of the fast mode's drift error; --training measures the training "
                  "step, which uses none" if case == "training" else
            "c.pt: trained at resolution 32 px but the camera renders 64 px")
    assert changed_outside(before, tree(tmp_path), "\0") == []


# ======================================================================================================
# docs/safety.md states the limits of a run that the code applies
# ======================================================================================================
def test_docs_safety_states_the_code_s_run_limits():
    from rhi.master.fit import data, priors
    from rhi.master.fit import estimator_settings as estimator
    from rhi.master.runtime import pool
    from tests.faults import REPO

    page = (REPO / "docs" / "safety.md").read_text()
    table = page.partition("<!-- run limits table")[2].split("\n\n")[0]
    values = [line.split("|")[2].strip().split()[0] for line in table.splitlines() if line.startswith("| ")][1:]
    assert values == [str(v) for v in (
        pool.WORKERS_PER_CORE, *(estimator.MAX_ESTIMATOR[key] for key in ("hidden_features", "transforms",
                                                                          "batch_size", "max_epochs", "threads",
                                                                          "ensemble")),
        f"{estimator.MAX_LEARNING_RATE:g}", priors.MAX_SIMULATIONS, f"{data.MAX_NOISE_SD:g}")]
    assert f"{estimator.FLOW_WEIGHTS_FACTOR} × transforms" in page
    assert f"{estimator.BYTES_PER_TRAINED_WEIGHT} bytes" in page
    assert f"{estimator.ACTIVATION_BYTES} bytes of activations" in page
