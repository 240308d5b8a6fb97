"""Settings for the test session, and the --quick decoders shared by the tests that need trained ones."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

# Passive OpenMP waiting, as `rhi` sets it in master.commands.cli.main (see the reason there): the tests
# load torch themselves, not through main(), and conftest runs before any test module imports it.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def quick_cache(tmp_path_factory):
    """A $RHI_CACHE folder holding the default --quick decoders (conv and vae), trained once per session.

    Trained in a child process (as `rhi experiment --quick` trains them: same settings, same cache names), so
    that training's torch thread settings stay out of this process. ``rhi experiment --quick`` with this
    RHI_CACHE finds them and trains nothing."""
    folder = tmp_path_factory.mktemp("decoders")
    code = ("from master.experiment import config; from master.experiment.decoders import ensure_checkpoints; "
            "ensure_checkpoints(config.load(quick=True), progress=False)")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env={**os.environ, "RHI_CACHE": str(folder)},
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return folder
