"""examples/orchestrate.py, the engine's worked example: it runs from a clean folder, its exported body
reproduces the native one, and its hand-made wiring gives the experiment's own drift."""
import ast
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import torch

from rhi.master import config as configuration
from rhi.master.decoders.cache import decoder_component
from rhi.master.tasks.illusion.measures import measures
from rhi.master.config.protocol import Trial
from rhi.master.tasks.illusion.wiring import run_batch

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "examples" / "orchestrate.py"
STEPS, RESOLUTION, SEED = 150, 16, 1  # the script's default seed


def test_example_uses_only_the_engine_the_export_and_the_components():
    modules = [alias.name if isinstance(node, ast.Import) else node.module
               for node in ast.walk(ast.parse(SCRIPT.read_text())) if isinstance(node, (ast.Import, ast.ImportFrom))
               for alias in node.names]
    project = sorted({m for m in modules if m.split(".")[0] == "rhi"})
    assert project and all(m.startswith(("rhi.components.", "rhi.master.cosim", "rhi.master.export"))
                           for m in project), project


def test_example_runs_and_its_drift_is_the_experiments(tmp_path):
    # One torch thread: quicker on a shared machine, and the decoder's sums depend on the thread count.
    env = {**os.environ, "RHI_CACHE": str(tmp_path / "cache"), "OMP_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, str(SCRIPT), "--tiny", "--out", "tiny", "--steps", str(STEPS),
                           "--resolution", str(RESOLUTION)], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    drifts = {body: float(value) for body, value in re.findall(r"^(native|FMU) body: +drift (\S+) cm$",
                                                                 done.stdout, re.MULTILINE)}
    assert set(drifts) == {"native", "FMU"}, done.stdout
    assert math.isfinite(drifts["native"]) and drifts["native"] < -1e-3  # toward the rubber hand, on the left
    assert abs(drifts["FMU"] - drifts["native"]) < 1e-9  # the exported body reproduces the native plant
    assert not (tmp_path / "cache").exists()  # the example trains nothing into the cache
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiny"]  # nor into the current folder: into --out

    # The same trial through the experiment's wiring and measures, with the decoder the script trained.
    config = configuration.load(overrides={"experiment.steps": STEPS, "experiment.resolution": RESOLUTION})
    assert config["decoder"]["visual_variance"] == 20.0  # the script's exact Decoder, at the default variance
    trial = Trial("conv", "left", "sync", 0, SEED, -0.15, 0.0, 0.1)
    decoder = decoder_component("conv", str(tmp_path / "tiny" / "tiny_decoder.pt"), config, fast=False)
    decoder.threads, threads = 1, torch.get_num_threads()  # as in the script's process
    try:
        expected = measures(run_batch(decoder, [trial], config))["drift_cm"][-1, 0]
    finally:
        torch.set_num_threads(threads)
    assert abs(drifts["native"] - expected) < 1e-9, (drifts["native"], expected)
