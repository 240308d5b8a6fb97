"""The rhi console script: help lists the design's commands; errors are one line with exit 2."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.in_process import rhi_in_process

COMMANDS = ("train", "experiment", "export-body", "export-agent", "export-system", "run-system", "sweep", "fit", "bench",
            "reach", "power")


def rhi(*args, cwd=None, env=None):
    return subprocess.run([sys.executable, "-m", "rhi", *args], capture_output=True, text=True, cwd=cwd, env=env,
                          timeout=300)


def test_help_lists_every_command():
    result = rhi("--help")
    assert result.returncode == 0
    for command in COMMANDS:
        assert command in result.stdout


def test_unknown_command_is_a_usage_error():
    result = rhi("fly")
    assert result.returncode == 2 and "invalid choice: 'fly'" in result.stderr


def test_passive_openmp_waiting_is_set_before_torch_loads():
    """main() sets OMP_WAIT_POLICY before a command runs, and importing the command line loads no torch, so
    OpenMP reads the setting; importing rhi.components.vision sets nothing (no import-time side effect)."""
    environment = {key: value for key, value in os.environ.items() if key != "OMP_WAIT_POLICY"}
    python = lambda code: subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,  # noqa: E731
                                         env=environment)
    result = python("import os, rhi.components.vision; print(os.environ.get('OMP_WAIT_POLICY'))")
    assert result.stdout.split() == ["None"], result.stderr
    result = python("import contextlib, io, os, sys; from rhi.master.commands.cli import main; print('torch' in sys.modules)\n"
                    "with contextlib.suppress(SystemExit), contextlib.redirect_stdout(io.StringIO()): main(['bench', '--help'])\n"
                    "print(os.environ.get('OMP_WAIT_POLICY'))")
    assert result.stdout.split() == ["False", "PASSIVE"], result.stderr


REFUSED_LOADS = """
import contextlib, io, sys
from rhi.master.commands.cli import main
with contextlib.suppress(SystemExit), contextlib.redirect_stderr(io.StringIO()) as said:
    main(sys.argv[1:])
print(said.getvalue().strip().splitlines()[-1])
print(sorted(name for name in ("torch", "scipy.special", "scipy.stats", "matplotlib") if name in sys.modules))
"""


FIT_TABLE = '[fit.parameters."brain.gamma0"]\nprior = "uniform"\nlow = 0.001\nhigh = 0.1\n'


@pytest.mark.parametrize("command, table", [(["experiment"], ""), (["reach"], ""), (["power", "--n", "10"], ""),
                                            (["sweep"], "[sweep]\ntrials = 1\n"),
                                            (["phenomenon", "time-course"], "[sweep]\ntrials = 1\n"),
                                            (["fit", "--data", "{tmp}/data.csv"], FIT_TABLE)])
def test_a_command_refused_for_its_configuration_loads_no_torch(tmp_path, command, table):
    """A refusal costs a process start, not torch's import (1.4 s of CPU on an AVX2 EPYC) or matplotlib's: the
    configuration, the commands' modules and the decoders' cache load torch, scipy's special functions and
    matplotlib only where they use them."""
    (tmp_path / "bad.toml").write_text("[brain]\nsigma_p = 1.0\n" + table)
    (tmp_path / "data.csv").write_text("participant,condition,stimulation,drift_cm\np,left,sync,-1.0\n")
    args = [part.format(tmp=tmp_path) for part in command] + ["--config", str(tmp_path / "bad.toml"),
                                                              "--out", str(tmp_path / "out")]
    result = subprocess.run([sys.executable, "-c", REFUSED_LOADS, *args], capture_output=True, text=True, timeout=120)
    said, loaded = result.stdout.strip().splitlines()
    assert said == f"rhi {command[0]}: error: unknown config key brain.sigma_p", result.stdout + result.stderr
    assert loaded == "[]", loaded
    assert not (tmp_path / "out").exists()


# Bad input for each command, and what its one line must say. {tmp} is a fresh folder; nothing may appear in it but
# what the test put there.
BAD_INPUT = {
    "train": (["--decoder", "conv", "--config", "{tmp}/bad.toml", "--out", "{tmp}/out.pt"],
              "unknown config key brain.sigma_p"),
    "experiment": (["--quick", "--config", "{tmp}/bad.toml", "--out", "{tmp}/out"], "unknown config key brain.sigma_p"),
    "export-body": (["--variant", "springy", "--out", "{tmp}/Body.fmu"], "--variant 'springy' is not one of"),
    "export-agent": (["--config", "{tmp}/bad.toml", "--out", "{tmp}/Agent.fmu"], "unknown config key brain.sigma_p"),
    "export-system": (["--quick", "--trial", "left/sync", "--out", "{tmp}/RHI.ssp"], "must be CONDITION/STIMULATION/INDEX"),
    "run-system": (["{tmp}/bad.toml", "--out", "{tmp}/out.csv"], "bad.toml is not an SSP package: it is not a zip"),
    "sweep": (["--config", "{tmp}/missing.toml", "--out", "{tmp}/out"], "missing.toml does not exist"),
    "fit": (["--data", "{tmp}/missing.csv", "--config", "{tmp}/bad.toml", "--out", "{tmp}/out"], "missing.csv does not exist"),
    "bench": (["--threads", "-2"], "--threads -2 must be 0 (all cores) to 1024 threads"),
    "reach": (["--config", "{tmp}/bad.toml", "--out", "{tmp}/out"], "unknown config key brain.sigma_p"),
    "power": (["--config", "{tmp}/bad.toml", "--n", "10,20", "--out", "{tmp}/out"], "unknown config key brain.sigma_p"),
}


@pytest.mark.parametrize("command", COMMANDS)
def test_bad_input_is_one_line_on_stderr_and_exit_status_2(command, tmp_path):
    assert set(BAD_INPUT) == set(COMMANDS)
    (tmp_path / "bad.toml").write_text("[brain]\nsigma_p = 2.0\n")
    arguments, expected = BAD_INPUT[command]
    # Run from the empty folder (so a stray write would show); main() in this process, as a fresh one would run
    # it (tests/in_process.py: the console script itself is the two tests above).
    result = rhi_in_process([command, *(a.format(tmp=tmp_path) for a in arguments)], tmp_path,
                            {"RHI_CACHE": str(tmp_path / "cache")})
    assert result.status == 2, (result.status, result.stderr[-2000:])
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"rhi {command}: error: ") and expected in lines[0], result.stderr
    assert "Traceback" not in result.stderr
    assert sorted(p.name for p in Path(tmp_path).iterdir()) == ["bad.toml"]  # nothing half-written


def test_every_command_is_one_module_of_the_table():
    """cli.COMMANDS names each command's module, which defines HELP, add_arguments and run; every module of
    master/commands but cli.py is one of them, and `rhi --help` lists exactly the table's commands."""
    import importlib

    from rhi.master.commands.cli import COMMANDS, build_parser

    folder = Path(importlib.import_module("rhi.master.commands").__file__).parent
    modules = {path.stem for path in folder.glob("*.py")} - {"__init__", "cli"}
    assert modules == set(COMMANDS.values())
    for module_name in COMMANDS.values():
        module = importlib.import_module(f"rhi.master.commands.{module_name}")
        assert isinstance(module.HELP, str) and callable(module.add_arguments) and callable(module.run)
    listed = build_parser()._subparsers._group_actions[0].choices
    assert list(listed) == list(COMMANDS)
