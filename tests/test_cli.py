"""The rhi console script: help lists the design's commands; errors are one line with exit 2."""
import os
import subprocess
import sys

COMMANDS = ("train", "experiment", "export-body", "sweep", "bench")


def rhi(*args):
    return subprocess.run([sys.executable, "-m", "master", *args], capture_output=True, text=True)


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
    OpenMP reads the setting; importing components.vision sets nothing (no import-time side effect)."""
    environment = {key: value for key, value in os.environ.items() if key != "OMP_WAIT_POLICY"}
    python = lambda code: subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,  # noqa: E731
                                         env=environment)
    result = python("import os, components.vision; print(os.environ.get('OMP_WAIT_POLICY'))")
    assert result.stdout.split() == ["None"], result.stderr
    result = python("import contextlib, io, os, sys; from master.commands.cli import main; print('torch' in sys.modules)\n"
                    "with contextlib.suppress(SystemExit), contextlib.redirect_stdout(io.StringIO()): main(['bench', '--help'])\n"
                    "print(os.environ.get('OMP_WAIT_POLICY'))")
    assert result.stdout.split() == ["False", "PASSIVE"], result.stderr
