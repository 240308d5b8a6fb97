"""Settings for the test session, and the --quick decoders shared by the tests that need trained ones."""
import os
import subprocess
import sys
from pathlib import Path

import pytest
from filelock import FileLock

# Passive OpenMP waiting, as `rhi` sets it in rhi.master.commands.cli.main (see the reason there): the tests
# load torch themselves, not through main(), and conftest runs before any test module imports it.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

ROOT = Path(__file__).resolve().parents[1]


# The modules that take longest run first (the longest first: a greedy schedule), so that under pytest-xdist (`make test`: two
# workers, a module to a worker) neither worker is left with a long module at the end. By their summed --durations on
# 2 cores of an AVX2 EPYC; a module not named here runs after these, in file order. The tutorial and the four after it
# need no --quick decoders, so the other worker runs them while the first trains them (the rest would wait on the lock).
FIRST = ("test_experiment.py", "test_tutorial.py", "test_hostile_bodies.py", "test_power.py", "test_logging.py",
         "test_figures.py", "test_models.py", "test_cli_catalogue.py", "test_phenomena.py", "test_doc_snippets.py",
         "test_sweep_resume.py", "test_sweep.py", "test_hostile_limits.py", "test_api.py", "test_bench.py",
         "test_paper.py", "test_hostile_files.py", "test_fit.py", "test_hostile_folders.py", "test_hostile_inputs.py",
         "test_reproducibility.py", "test_cli_runs.py", "test_parallel.py", "test_shipped.py", "test_fast_check.py",
         "test_fast.py")


def pytest_configure(config):
    # pytest-xdist (3.x) otherwise hands out the modules by their number of tests, most first, whatever the order
    # above: a module of one long test (the tutorial's) then starts last and one worker waits on it alone.
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


def pytest_collection_modifyitems(items):
    rank = {name: position for position, name in enumerate(FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(FIRST)))  # stable: file order kept otherwise
    if os.environ.get("RHI_TEST_ORDER") == "reversed":  # a check that no test leans on one run before it
        items.reverse()


@pytest.fixture(autouse=True)
def own_decoder_cache(tmp_path_factory, monkeypatch):
    """Every test's $RHI_CACHE is an empty folder of its own, never the user's ~/.cache/rhi: no test reads what
    the machine or an earlier test left there, and none writes into the home folder. A test that needs trained
    decoders asks for :func:`quick_cache` and points RHI_CACHE at it."""
    monkeypatch.setenv("RHI_CACHE", str(tmp_path_factory.mktemp("rhi-cache")))


def train_quick_decoders(folder: Path) -> None:
    code = ("from rhi.master import config; from rhi.master.decoders.cache import ensure_checkpoints; "
            "ensure_checkpoints(config.load(quick=True), progress=False)")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env={**os.environ, "RHI_CACHE": str(folder)},
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]


def made_once(tmp_path_factory, worker_id, name: str, make) -> Path:
    """A folder ``name`` that ``make(folder)`` fills once per test run. Under pytest-xdist the workers share one
    folder beside their own temporary folders: the first to take the lock makes it, the others wait and find it."""
    if worker_id == "master":  # not under xdist
        folder = tmp_path_factory.mktemp(name)
        make(folder)
        return folder
    shared = tmp_path_factory.getbasetemp().parent / name
    with FileLock(str(shared) + ".lock"):
        if not (shared / "complete").exists():
            shared.mkdir(exist_ok=True)
            make(shared)
            (shared / "complete").touch()
    return shared


@pytest.fixture(scope="session")
def quick_cache(tmp_path_factory, worker_id):
    """A $RHI_CACHE folder holding the default --quick decoders (conv and vae), trained once per test run.

    Trained in a child process (as `rhi experiment --quick` trains them: same settings, same cache names), so
    that training's torch thread settings stay out of this process. ``rhi experiment --quick`` with this
    RHI_CACHE finds them and trains nothing."""
    return made_once(tmp_path_factory, worker_id, "decoders", train_quick_decoders)


@pytest.fixture(scope="session")
def fault_resources(tmp_path_factory, worker_id):
    """tests/faults.py's tiny checkpoints and faulty FMUs, made once per test run (read only by the tests)."""
    from tests.faults import make_resources, resources_at

    return resources_at(made_once(tmp_path_factory, worker_id, "fault-resources", make_resources))
