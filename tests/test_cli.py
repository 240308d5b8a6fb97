"""The rhi console script: help lists the design's commands; errors are one line with exit 2."""
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
