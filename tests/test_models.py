"""Models and tasks as registered objects: the registries, a user's model and task in one file each, and every task x
every model run end to end at tiny size, in memory and from the command line, the same tables both ways (the
shipped 64 px decoders and pose encoders: nothing trained).

Truth: the fixed-gamma example's gamma is the configuration's value at every step (its brain never updates it),
so its synchronous and asynchronous trials, which differ only in their delays, give the same numbers to the
last bit; the registry's refusals are read off the files written here."""
import csv
import inspect
import re
from pathlib import Path

import numpy as np
import pytest

from rhi.master import models
from rhi.master.commands.cli import main
from rhi.master.cosim import ConfigError
from rhi.master.models.paper import PaperModel
from rhi.master import tasks
from rhi.master.tasks import TASKS, Task
from rhi.master.tasks.base import table_text
from rhi.master import config as configuration

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = f"{ROOT / 'examples' / 'my_model.py'}:FixedGamma"
EXAMPLE_TASK = f"{ROOT / 'examples' / 'my_task.py'}:MovedArm"
EXAMPLE_TINY = "[moved_arm]\nmove_time_s = 0.12\n"  # the move at the middle of the tiny trial
MODELS = ("paper", "causal", "ownership", EXAMPLE)
TINY = {  # each registered task at tiny size: one decoder, one condition, a few steps of 0.02 s
    "illusion": "[experiment]\nsteps = 12\ntrials = 1\ndecoders = [\"conv\"]\nconditions = [\"left\"]\n",
    "reach": "[experiment]\nsteps = 12\ndecoders = [\"conv\"]\n[reach]\ngoals = 1\nbands = [\"near\"]\n",
    "moving-hand": "[experiment]\nsteps = 12\ndecoders = [\"conv\"]\n[moving_hand]\ndelays = [0.0, 0.1]\n"
                   "period = 0.2\n",
    "reach-after": "[experiment]\ndecoders = [\"conv\"]\nconditions = [\"left\"]\nstimulations = [\"sync\"]\n"
                   "trials = 1\n[reach_after]\nrelease = 0.12\nwindow = 0.12\n",
}


def test_every_registered_task_has_a_tiny_size_here():
    assert set(TINY) == set(TASKS) and EXAMPLE_TASK not in TASKS  # a file's task resolves, never registers


def test_every_task_declares_the_contract_with_one_signature():
    """Every task's contract methods take the base's arguments, by name and in order (one signature for all)."""
    contract = ("load", "plan", "scenario", "parameters", "measures", "tables", "figures", "simulate")
    for name in (*TASKS, EXAMPLE_TASK):
        task = tasks.get(name)
        for method in contract:
            assert list(inspect.signature(getattr(task, method)).parameters) == \
                list(inspect.signature(getattr(Task(), method)).parameters), (name, method)


def command_of(task: str) -> list[str]:
    """The command that runs ``task``: a built-in's own (rhi experiment, rhi phenomenon moving-hand), else rhi run."""
    return tasks.get(task).command.split()[1:] if task in TASKS else ["run", task]


class EntryPointModel(PaperModel):
    """The paper's model under another name, as a package's entry point would register it."""

    name = "entry-point"
    settings_file = ""

@pytest.mark.parametrize("model", MODELS, ids=("paper", "causal", "ownership", "example"))
@pytest.mark.parametrize("task", (*TASKS, EXAMPLE_TASK), ids=(*TASKS, "example"))
def test_every_task_runs_every_model_in_memory_and_from_the_command_line(task, model, tmp_path, capsys):
    """Each task x model end to end at tiny size: from its command, and in memory (rhi.master.tasks.run), the same
    tables to the byte (one writer: the command writes what the in-memory result holds)."""
    (tmp_path / "tiny.toml").write_text(TINY.get(task, TINY["illusion"] + EXAMPLE_TINY))
    command = [*command_of(task), "--model", model, "--config", str(tmp_path / "tiny.toml"), "--out",
               str(tmp_path / "out")]
    assert main(command) == 0, capsys.readouterr().err[-2000:]
    written = sorted((tmp_path / "out").glob("*.csv"))
    assert written, "no table written"
    assert all(list(csv.DictReader(table.open())) for table in written)  # each table has rows
    run = (tmp_path / "out" / "run.json").read_text()
    assert f'"model": "{models.get(model).name}"' in run
    chosen = tasks.get(task)
    in_memory = tasks.run(chosen, chosen.load(tmp_path / "tiny.toml", model_name=model)).tables()
    assert sorted(in_memory) == [path.name for path in written]
    for name, table in in_memory.items():
        assert table_text(table) == (tmp_path / "out" / name).read_text(), name


def test_the_example_task_moves_the_arm_at_its_time_and_not_before():
    """examples/my_task.py: until the move the trial is the one without a move, to the last bit (the arm has not
    moved); at the end the drift differs (the decoder now sees the arm 10 cm further away)."""
    task = tasks.get(EXAMPLE_TASK)
    config = task.load(overrides={"experiment.steps": 12, "experiment.decoders": ["conv"],
                                  "experiment.conditions": ["left"], "experiment.stimulations": ["sync"],
                                  "experiment.trials": 1, "moved_arm.move_time_s": 0.12})
    moved, still = (tasks.run(task, configuration.merge(config, {"moved_arm": {"shift_cm": shift}}))
                    for shift in (10.0, 0.0))
    before = task.before(moved.times, config)
    assert moved.times[before] < 0.12 <= moved.times[before + 1]
    assert np.array_equal(moved.per_step["drift_cm"][:before + 1], still.per_step["drift_cm"][:before + 1])
    assert moved.per_step["drift_cm"][-1, 0] != still.per_step["drift_cm"][-1, 0]
    frame = moved.tables()["drift.csv"]
    assert frame["drift_before_cm"][0] == moved.per_step["drift_cm"][before, 0]


def test_the_example_task_runs_as_a_sweep(tmp_path, capsys):
    """[sweep] task = "examples/my_task.py:MovedArm": each trial through the task's outcome; with no shift it is the
    illusion's own trial (the same batch of one, the same bits), with 10 cm it is not."""
    (tmp_path / "sweep.toml").write_text(
        '[experiment]\nsteps = 12\ndecoders = ["conv"]\nconditions = ["left"]\nstimulations = ["sync"]\n'
        f'[moved_arm]\nmove_time_s = 0.12\n[sweep]\ntask = "{EXAMPLE_TASK}"\ntrials = 1\nworkers = 1\n'
        '[sweep.grid]\n"moved_arm.shift_cm" = [0.0, 10.0]\n')
    assert main(["sweep", "--config", str(tmp_path / "sweep.toml"), "--out", str(tmp_path / "sweep")]) == 0, \
        capsys.readouterr().err[-2000:]
    rows = {float(row["moved_arm.shift_cm"]): float(row["drift_cm"])
            for row in csv.DictReader((tmp_path / "sweep" / "index.csv").open())}
    illusion = tasks.get("illusion")
    config = illusion.load(overrides={"experiment.steps": 12, "experiment.decoders": ["conv"],
                                      "experiment.conditions": ["left"], "experiment.stimulations": ["sync"],
                                      "experiment.trials": 1})
    alone = illusion.outcome(config, illusion.plan(config)[0])["drift_cm"]
    assert rows[0.0] == alone and rows[10.0] != alone


@pytest.mark.parametrize("body, message", [
    ("", "has no Mine"),
    ("Mine = 3\n", "Mine is not a rhi.master.tasks.Task"),
    ("from rhi.master.tasks import Task\nclass Mine(Task):\n    name = 'Bad Name'\n", "name must be lower-case"),
    ("from rhi.master.tasks import Task\nclass Mine(Task):\n    name = 'mine'\n    summary = 'x'\n",
     "plan() is not defined"),
    ("raise RuntimeError('boom')\n", "RuntimeError: boom"),
])
def test_a_bad_task_file_is_one_line(tmp_path, body, message):
    (tmp_path / "mine.py").write_text(body)
    with pytest.raises(ConfigError, match=re.escape(message)) as caught:
        tasks.get(f"{tmp_path / 'mine.py'}:Mine")
    assert "\n" not in str(caught.value)


def test_a_task_refused_on_the_command_line_is_exit_2_and_one_line(tmp_path, capsys):
    """An unknown task (rhi run), and one without export hooks (export-agent --task): one line, exit 2, no file."""
    for command, message in ((["run", "nope", "--out", str(tmp_path / "out")], "task 'nope' is unknown"),
                             (["export-agent", "--quick", "--task", "moving-hand", "--out", str(tmp_path / "A.fmu")],
                              "--task 'moving-hand' is not one of illusion, reach")):
        assert main(command) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_the_example_model_holds_gamma_and_so_ignores_the_timing(tmp_path, capsys):
    (tmp_path / "tiny.toml").write_text("[experiment]\nsteps = 120\ntrials = 1\ndecoders = [\"conv\"]\n"
                                        "conditions = [\"left\"]\n[fixed_gamma]\ngamma = 0.3\n")
    assert main(["experiment", "--model", EXAMPLE, "--config", str(tmp_path / "tiny.toml"), "--out",
                 str(tmp_path / "out")]) == 0, capsys.readouterr().err[-2000:]
    rows = {row["stimulation"]: row for row in csv.DictReader((tmp_path / "out" / "summary.csv").open())}
    assert float(rows["sync"]["gamma_final_mean"]) == 0.3 and float(rows["async"]["gamma_final_mean"]) == 0.3
    assert rows["sync"]["drift_cm_mean"] == rows["async"]["drift_cm_mean"]  # the delays reach nothing else
    assert float(rows["sync"]["drift_cm_mean"]) < 0  # vision pulls the belief toward the rubber hand (left)


def test_the_example_model_runs_a_sweep_and_a_fit(quick_cache, tmp_path, monkeypatch, capsys):
    from tests.test_fit import DATA, FIT

    monkeypatch.setenv("RHI_CACHE", str(quick_cache))
    (tmp_path / "sweep.toml").write_text(
        f'[experiment]\nsteps = 8\ndecoders = ["conv"]\nconditions = ["left"]\n[sweep]\nquick = true\n'
        f'model = "{EXAMPLE}"\nworkers = 1\n[sweep.grid]\n"fixed_gamma.gamma" = [0.1, 0.9]\n')
    assert main(["sweep", "--config", str(tmp_path / "sweep.toml"), "--out", str(tmp_path / "sweep")]) == 0, \
        capsys.readouterr().err[-2000:]
    rows = list(csv.DictReader((tmp_path / "sweep" / "index.csv").open()))
    assert sorted({float(row["gamma_final"]) for row in rows}) == [0.1, 0.9]  # each point's own gamma, held
    fit = FIT.format(steps=8, simulations=20, calibration=0).replace('[fit.parameters."decoder.visual_variance"]',
                                                                   '[fit.parameters."fixed_gamma.gamma"]')
    fit = fit.replace('prior = "log-uniform"\nlow = 5.0\nhigh = 80.0', 'prior = "uniform"\nlow = 0.05\nhigh = 0.95')
    (tmp_path / "fit.toml").write_text(fit)
    (tmp_path / "data.csv").write_text(DATA)
    assert main(["fit", "--data", str(tmp_path / "data.csv"), "--config", str(tmp_path / "fit.toml"), "--model",
                 EXAMPLE, "--out", str(tmp_path / "fit")]) == 0, capsys.readouterr().err[-2000:]
    samples = [float(row["fixed_gamma.gamma"]) for row in csv.DictReader((tmp_path / "fit" / "posterior.csv").open())]
    assert len(samples) == 50 and all(0.05 <= value <= 0.95 for value in samples)  # within the prior's support


def test_the_registry_names_the_built_in_models_and_resolves_a_file():
    assert models.names()[:3] == ("paper", "causal", "ownership")
    assert models.get("causal") is models.get("causal")  # once per process
    example = models.get(EXAMPLE)
    assert example.name == "fixed-gamma" and example.source == EXAMPLE
    config = configuration.load(model_name=EXAMPLE)
    assert config["model"] == {"name": "fixed-gamma", "source": EXAMPLE} and config["fixed_gamma"]["gamma"] == 0.5
    assert models.of(config) is example and models.of(configuration.load()).name == "paper"
    assert "model" not in configuration.load()  # the defaults are the paper's model: nothing added


@pytest.mark.parametrize("body, message", [
    ("", "has no Mine"),
    ("Mine = 3\n", "Mine is not a rhi.master.models.Model"),
    ("from rhi.master.models import Model\nclass Mine(Model):\n    name = 'Bad Name'\n", "name must be lower-case"),
    ("from rhi.master.models import Model\nclass Mine(Model):\n    name = 'mine'\n", "brain() failed: NotImplementedError"),
    ("from rhi.master.models.paper import PaperModel\nclass Mine(PaperModel):\n    name = 'mine'\n"
     "    parameter_sources = {'brain.nope': 'brain.gamma0'}\n", "names brain.nope, not a parameter its brain declares"),
    ("from rhi.master.models.paper import PaperModel\nclass Mine(PaperModel):\n    name = 'mine'\n"
     "    links = [('camera', 'brain.x')]\n", "links must be ('component.output', 'component.input') pairs"),
    ("raise RuntimeError('boom')\n", "RuntimeError: boom"),
])
def test_a_bad_model_file_is_one_line(tmp_path, body, message):
    (tmp_path / "mine.py").write_text(body)
    with pytest.raises(ConfigError, match=re.escape(message)) as caught:
        models.get(f"{tmp_path / 'mine.py'}:Mine")
    assert "\n" not in str(caught.value)


def test_a_bad_model_name_on_the_command_line_is_exit_2_and_one_line(tmp_path, capsys):
    for name, message in (("nope", "model 'nope' is unknown; choose one of paper, causal"),
                          (f"{tmp_path}/missing.py:Mine", "no file")):
        assert main(["experiment", "--model", name, "--out", str(tmp_path / "out")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err
    assert not (tmp_path / "out").exists()


def test_no_model_name_is_tested_outside_the_registry():
    """A model is chosen through the registry, never by comparing its name (docs/architecture.md)."""
    pattern = re.compile(r"""model.*?[!=]=\s*["'](causal|paper)["']|["']causal["']\s+in\s+config|MODELS\s*=""")
    found = [f"{path.relative_to(ROOT)}:{number}: {line.strip()}"
             for path in sorted((ROOT / "master").rglob("*.py")) if "models" not in path.relative_to(ROOT).parts
             for number, line in enumerate(path.read_text().splitlines(), 1) if pattern.search(line)]
    assert not found, "\n".join(found)


def test_the_model_parameters_reach_the_brain_per_trial():
    """A batch whose trials carry their own fixed_gamma.gamma gives each its own brain.gamma0 (a fit's batch)."""
    from rhi.master.tasks.illusion import make_trial
    from rhi.master.config import sources
    from rhi.master.tasks.illusion import wiring

    base = configuration.load(quick=True, model_name=EXAMPLE)
    trials = [make_trial(base, "conv", "left", "sync", 0, (("fixed_gamma.gamma", value),)) for value in (0.2, 0.7)]
    assert "fixed_gamma.gamma" in sources.batchable_keys(base)
    assert np.array_equal(wiring.parameters(trials, base)["brain.gamma0"], [0.2, 0.7])


def test_export_agent_carries_a_model_of_ones_own_and_refuses_one_it_cannot_carry(quick_cache, tmp_path, monkeypatch,
                                                                                   capsys):
    """rhi export-agent --model: the example's agent FMU, stepped by fmpy, holds gamma at fixed_gamma.gamma (its
    brain, not the paper's, is inside); the causal model, whose pose encoder the FMU does not carry, is refused."""
    from fmpy.validation import validate_fmu

    from tests.test_agent import drive_by_hand

    monkeypatch.setenv("RHI_CACHE", str(quick_cache))
    (tmp_path / "g.toml").write_text("[fixed_gamma]\ngamma = 0.25\n")
    fmu = tmp_path / "Agent.fmu"
    assert main(["export-agent", "--quick", "--decoder", "conv", "--model", EXAMPLE, "--config",
                 str(tmp_path / "g.toml"), "--out", str(fmu)]) == 0, capsys.readouterr().err[-2000:]
    assert validate_fmu(str(fmu)) == []
    stepped = drive_by_hand(fmu, 120, reals={"delay_min": 0.0, "delay_max": 0.1, "period": 0.4})
    assert np.all(stepped["gamma"] == 0.25) and np.ptp(stepped["mu_shoulder"]) > 0  # held gamma, a moving belief
    assert main(["export-agent", "--quick", "--model", "causal", "--out", str(tmp_path / "C.fmu")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pose encoder, which the agent FMU does not carry" in err[0], err
    assert not (tmp_path / "C.fmu").exists()


def test_a_model_registered_as_an_entry_point_is_found_by_its_name(monkeypatch):
    """A package's ``[project.entry-points."rhi.models"]`` names a model: --model takes its name (the entry points
    as importlib.metadata lists them, here one made up in the group), and its configuration records the spec."""
    from importlib.metadata import EntryPoint

    point = EntryPoint(name="mine", value="tests.test_models:EntryPointModel", group=models.ENTRY_POINT_GROUP)
    monkeypatch.setattr(models.metadata, "entry_points", lambda group: [point] if group == point.group else [])
    assert models.names() == ("paper", "causal", "ownership", "mine")
    model = models.get("mine")
    assert model.name == "entry-point" and model.source == point.value
    assert configuration.load(model_name="mine")["model"] == {"name": "entry-point", "source": point.value}


def test_a_model_without_its_pose_encoder_at_this_resolution_is_refused_before_any_work(tmp_path, capsys):
    """--model causal --quick (32 px: no shipped pose encoder there) is one line and exit 2 before any decoder is
    trained or checked, from rhi experiment and from rhi phenomenon alike, and nothing is written."""
    (tmp_path / "quick.toml").write_text("[sweep]\nquick = true\n[experiment]\ndecoders = [\"conv\"]\n"
                                         "conditions = [\"right\"]\nstimulations = [\"sync\"]\n")
    for command in (["experiment", "--quick", "--model", "causal", "--out", str(tmp_path / "out")],
                    ["phenomenon", "distance", "--model", "causal", "--config", str(tmp_path / "quick.toml"), "--out",
                     str(tmp_path / "out")]):
        assert main(command) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "no shipped conv pose encoder at 32 px" in err[0], err
        assert not (tmp_path / "out").exists()


def test_a_phenomenon_refused_at_its_scheduler_leaves_no_folder(tmp_path, capsys):
    """rhi phenomenon --scheduler garbage: one line, exit 2, and the folder it made is gone (it was empty)."""
    (tmp_path / "tiny.toml").write_text("[sweep]\nquick = true\n[experiment]\ndecoders = [\"conv\"]\n"
                                        "conditions = [\"right\"]\nstimulations = [\"sync\"]\n")
    assert main(["phenomenon", "distance", "--model", "paper", "--config", str(tmp_path / "tiny.toml"), "--scheduler",
                 "garbage", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "garbage" in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiny.toml"]
