"""The command line's log: -q prints nothing but errors, -v the run's steps; Python's warnings go through it; off a
terminal a progress bar is whole lines, never a carriage return (a log file holds no overwritten bars)."""
import io
import logging
import os
import subprocess
import sys
import warnings
from contextlib import redirect_stderr
from pathlib import Path

from rhi.master.runtime.logs import configured
from rhi.master.runtime import progress

ROOT = Path(__file__).resolve().parents[1]
# the smallest experiment: one trial of one cell, 10 steps, on the shipped conv decoder (nothing to train)
TINY = """[experiment]
trials = 1
steps = 10
conditions = ["left"]
stimulations = ["sync"]
decoders = ["conv"]
"""


def said(verbosity: int, emit) -> str:
    """What ``emit()`` writes on stderr under the command line's log at ``verbosity``."""
    stream = io.StringIO()
    with redirect_stderr(stream), configured(verbosity):
        emit()
    return stream.getvalue()


def test_each_level_shows_what_it_says():
    def emit():
        log = logging.getLogger("rhi.experiment")
        log.debug("a step")
        log.info("a note")
        log.error("rhi experiment: an error")

    assert said(-1, emit) == "rhi experiment: an error\n"
    assert said(0, emit) == "a note\nrhi experiment: an error\n"
    assert said(1, emit) == "debug: a step\na note\nrhi experiment: an error\n"
    assert logging.getLogger("rhi").handlers == [] and not logging.getLogger("rhi").disabled  # as it was


def test_python_s_warnings_are_one_logged_line_and_quiet_hides_them():
    def emit():
        with warnings.catch_warnings():
            warnings.simplefilter("always")
            warnings.warn("network has not yet fully converged", UserWarning)

    shown = said(0, emit).splitlines()
    assert len(shown) == 1 and shown[0].startswith("rhi: warning: ") and shown[0].endswith(
        "UserWarning: network has not yet fully converged")
    assert said(-1, emit) == ""


def test_off_a_terminal_a_bar_is_whole_lines_at_most_every_few_seconds():
    stream = io.StringIO()  # not a terminal
    with redirect_stderr(stream):
        with progress.bar(total=1000, desc="steps", leave=False, position=3) as shown:
            for _ in range(1000):
                shown.update(1)
    text = stream.getvalue()
    lines = text.splitlines()
    assert "\r" not in text and "\x1b" not in text  # no carriage return, no cursor move for position=3
    # well under LINE_EVERY_S: tqdm shows it only when made and when closed (kept, though leave=False)
    assert len(lines) == 2 and lines[0].startswith("steps:   0%") and "1000/1000" in lines[1]


def test_quiet_shows_no_bar():
    stream = io.StringIO()
    with redirect_stderr(stream), configured(-1):
        with progress.bar(total=3) as shown:
            shown.update(3)
    assert stream.getvalue() == ""


def run_cli(tmp_path, *options):
    """``rhi OPTIONS experiment`` on the tiny configuration in a child process, stdout and stderr to files."""
    (tmp_path / "tiny.toml").write_text(TINY)
    home = tmp_path / "home"
    home.mkdir(exist_ok=True)
    environment = {**os.environ, "HOME": str(home), "RHI_CACHE": str(home / "cache"), "PYTHONPATH": str(ROOT)}
    out = tmp_path / f"out{len(options)}{''.join(options)}"
    with open(tmp_path / "stdout", "wb") as stdout, open(tmp_path / "stderr", "wb") as stderr:
        done = subprocess.run([sys.executable, "-m", "rhi.master.commands.cli", *options, "experiment", "--config",
                               str(tmp_path / "tiny.toml"), "--out", str(out)], stdout=stdout, stderr=stderr,
                              env=environment, cwd=tmp_path, timeout=300)
    return done.returncode, out, (tmp_path / "stdout").read_text(), (tmp_path / "stderr").read_text()


def test_quiet_experiment_prints_nothing(tmp_path):
    status, out, stdout, stderr = run_cli(tmp_path, "-q")
    assert (status, stdout, stderr) == (0, "", "")
    assert (out / "summary.csv").is_file()  # it ran, silently


def test_a_verbose_log_file_has_the_run_s_steps_and_no_overwritten_bar(tmp_path):
    status, out, stdout, stderr = run_cli(tmp_path, "-v")
    assert status == 0 and stdout.startswith(f"wrote {out}: ")
    assert "\r" not in stderr and "\x1b" not in stderr
    lines = stderr.splitlines()
    assert "debug: model paper: decoders conv, 1 conditions x 1 stimulations x 1 trials x 10 steps" in lines
    assert any(line.startswith("debug: conv trials x1: 10 steps in ") for line in lines)
    assert any(line.startswith("conv trials x1: 100%") and "10/10" in line for line in lines)


def test_training_missing_decoders_says_so_in_one_logged_line(tmp_path, monkeypatch):
    """With progress on and the cache empty, the decoders to train are named in the log (the training itself is
    stood in for: what is checked is the line, which once raised a TypeError before any training)."""
    from rhi.master import config as configuration
    from rhi.master.decoders import cache, training

    monkeypatch.setenv("RHI_CACHE", str(tmp_path))
    monkeypatch.setattr(training, "prepare_data", lambda *args: None)  # the cache imports it where it trains
    monkeypatch.setattr(cache, "run_jobs", lambda function, jobs, *rest: [(None, {"train": 1.0}) for _ in jobs])
    config = configuration.load(quick=True, overrides={"experiment.decoders": ["conv"]})
    text = said(1, lambda: cache.ensure_checkpoints(config, progress=True))
    assert "training the conv decoder side by side" in text and str(tmp_path) in text
