"""The command line against a hostile machine: an interrupt swallowed on its way, a broken model plug-in, a
closed or ASCII-only stdout (docs/configuration.md, "What rhi refuses and what it guarantees")."""
from __future__ import annotations

import gc
import os
import signal

import pytest


@pytest.fixture
def signals_kept():
    """The test process's own SIGINT and SIGTERM handlers, put back after a test that lets rhi change them."""
    kept = {number: signal.getsignal(number) for number in (signal.SIGINT, signal.SIGTERM)}
    yield
    for number, handler in kept.items():
        signal.signal(number, handler)


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")  # the swallowed one, on purpose
def test_an_interrupt_swallowed_in_a_gc_callback_still_ends_the_run_with_130(monkeypatch, capsys, signals_kept):
    """Ctrl-C delivered while a garbage-collection callback runs: Python prints "Exception ignored" and goes on.
    The run must not then finish as if nothing happened (exit 0), and the next signal must still act (its
    default action, never SIG_IGN)."""
    from rhi.master.commands import bench
    from rhi.master.commands.cli import main

    seen = {}

    def callback(phase, info):
        if phase == "start" and "fired" not in seen:
            seen["fired"] = True
            os.kill(os.getpid(), signal.SIGINT)  # handled here, inside the callback: the exception is swallowed

    def run(args):
        gc.callbacks.append(callback)
        try:
            gc.collect()
        finally:
            gc.callbacks.remove(callback)
        seen["after"] = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
        return 0

    monkeypatch.setattr(bench, "run", run)
    status = main(["bench"])
    err = capsys.readouterr().err
    assert seen["fired"]
    assert seen["after"] == (signal.SIG_DFL, signal.SIG_DFL)  # a second Ctrl-C or SIGTERM ends the process
    assert status == 130 and "rhi bench: interrupted by Ctrl-C" in err, err


def broken_plug_in(root, monkeypatch, body: str = "raise RuntimeError('this plug-in is broken')\n") -> None:
    """An installed package whose `rhi.models` entry point ``broken`` names a module that raises when imported: a
    dist-info folder on sys.path, as pip leaves one (importlib.metadata finds it there)."""
    (root / "broken_rhi_model.py").write_text(body)
    info = root / "broken_rhi_model-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-rhi-model\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[rhi.models]\nbroken = broken_rhi_model:Model\n")
    monkeypatch.syspath_prepend(str(root))


@pytest.mark.parametrize("body", ["raise RuntimeError('this plug-in is broken')\n", "import sys\nsys.exit(0)\n"])
def test_one_broken_model_entry_point_breaks_only_a_run_that_uses_it(tmp_path, monkeypatch, capsys, body):
    from rhi.master.commands.cli import main

    broken_plug_in(tmp_path, monkeypatch, body)
    for argv in (["--version"], ["--help"], ["experiment", "--help"]):
        with pytest.raises(SystemExit) as done:
            main(argv)
        out, err = capsys.readouterr()
        assert done.value.code == 0 and "Traceback" not in err, err
    assert "broken = broken_rhi_model:Model" in " ".join(out.split())  # named in --model's help, not imported
    status = main(["experiment", "--model", "broken", "--quick", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert status == 2 and len(err.strip().splitlines()) == 1 and "model 'broken_rhi_model:Model'" in err, err
    assert not (tmp_path / "out").exists()


# -- a user's model plug-in that is wrong is one refusal line, a brain that fails a step a failed trial ------
PLUG_IN_HEAD = "from rhi.components.brain.integrator import Brain\nfrom rhi.master.models.paper import PaperModel\n\n\n"
BAD_PLUG_INS = {
    "RaisesInInit": ("class RaisesInInit(PaperModel):\n    name = 'bad'\n    def __init__(self):\n"
                     "        raise RuntimeError('no')\n", "RaisesInInit() raised RuntimeError: no"),
    "NeedsArguments": ("class NeedsArguments(PaperModel):\n    name = 'bad'\n    def __init__(self, size):\n"
                       "        pass\n", "NeedsArguments() raised TypeError"),
    "SettingsList": ("class SettingsList(PaperModel):\n    name = 'bad'\n    own_settings = ['x']\n",
                     "own_settings must be a dict, got list"),
    "ModelNotATable": ("class ModelNotATable(PaperModel):\n    name = 'bad'\n    own_settings = {'model': 'x'}\n",
                       "own_settings' model must be a table"),
    "SourcesList": ("class SourcesList(PaperModel):\n    name = 'bad'\n    parameter_sources = ['brain.gamma0']\n",
                    "parameter_sources must be a dict, got list"),
    "UnrecordedMeasure": ("class UnrecordedMeasure(PaperModel):\n    name = 'bad'\n"
                          "    measures = {'x_cm': 'brain.nothing'}\n", "measures['x_cm'] = 'brain.nothing'"),
    "ExitsAtImport": ("import sys\nsys.exit(0)\n", "SystemExit"),
}


@pytest.mark.parametrize("name", BAD_PLUG_INS)
def test_a_model_plug_in_that_is_wrong_is_one_refusal_line(tmp_path, name):
    from tests.faults import refused, rhi

    body, says = BAD_PLUG_INS[name]
    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "m.py").write_text(PLUG_IN_HEAD + body)
    done = rhi(tmp_path, "experiment", "--quick", "--model", f"m.py:{name}", "--out", "out")
    refused(done, says)
    assert sorted(p.name for p in (tmp_path / "work").iterdir()) == ["m.py"]


RAISING_BRAIN = PLUG_IN_HEAD + '''class RaisingBrain(Brain):
    def step(self, t, h):
        if t > 0.05:
            raise ValueError("this brain cannot go on")
        super().step(t, h)


class Raising(PaperModel):
    name = "raising"

    def brain(self):
        return RaisingBrain()
'''


def test_a_brain_that_raises_in_a_step_is_a_failed_trial_not_a_traceback(tmp_path, fault_resources):
    from tests.faults import CONV_ONLY, expand, experiment
    from tests.in_process import rhi_in_process

    work = tmp_path / "work"
    work.mkdir()
    (work / "conv_only.toml").write_text(CONV_ONLY + "[decoder]\nfast = false\n")
    (work / "m.py").write_text(RAISING_BRAIN)
    args = [expand(a, fault_resources) for a in experiment("--model", "m.py:Raising", "--out", "out")]
    done = rhi_in_process(args, work, {"RHI_CACHE": str(tmp_path / "cache")}, timeout=240)
    assert done.status == 1 and "Traceback" not in done.stderr, done.stderr[-3000:]
    assert "ValueError: this brain cannot go on" in done.stderr, done.stderr[-3000:]


# -- a closed stdout, an ASCII-only one ------------------------------------------------------------------
def rhi_process(cwd, *args, env=(), close_stdout=False):
    import subprocess
    import sys

    from tests.faults import ENV

    return subprocess.run([sys.executable, "-m", "rhi", *args], cwd=cwd, capture_output=not close_stdout,
                          stderr=subprocess.PIPE if close_stdout else None, text=True, timeout=300,
                          env={**ENV, **dict(env)}, preexec_fn=(lambda: os.close(1)) if close_stdout else None)


def test_a_closed_stdout_is_one_line_and_exit_1_and_the_file_is_whole(tmp_path):
    import zipfile

    done = rhi_process(tmp_path, "export-body", "--out", "Body.fmu", close_stdout=True)
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert done.stderr.strip().splitlines() == ["rhi export-body: error: cannot write to standard output "
                                                "(Bad file descriptor)"], done.stderr
    with zipfile.ZipFile(tmp_path / "Body.fmu") as archive:
        assert archive.testzip() is None and "modelDescription.xml" in archive.namelist()


def test_a_non_ascii_out_under_an_ascii_stdout_is_escaped_not_an_error(tmp_path):
    done = rhi_process(tmp_path, "export-body", "--out", "Körper.fmu", env={"PYTHONIOENCODING": "ascii"})
    assert done.returncode == 0 and done.stderr == "", done.stderr[-2000:]
    assert "wrote K\\xf6rper.fmu" in done.stdout and (tmp_path / "Körper.fmu").is_file()
