"""Sweep files and their checks for the sweep tests: stand-in sweeps (tests/sweep_tasks.py), the experiment's
own lockstep sweeps at quick size, and the truth each is compared with, computed here."""
import argparse
import json
import os
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

from tests.sweep_tasks import fake_outcome

REPO = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
DASK = Path(sys.executable).with_name("dask")


def sweep_file(path, grid=None, points=None, task="fake_outcome", trials=2, conditions=("left", "right"),
               workers=2, extra=""):
    lines = ["[experiment]", 'decoders = ["conv"]', f"conditions = {json.dumps(list(conditions))}",
             'stimulations = ["sync"]', extra, "[sweep]", f"trials = {trials}", f"workers = {workers}",
             f'task = "tests.sweep_tasks:{task}"']
    if grid is not None:
        lines += ["[sweep.grid]", *(f'"{key}" = {json.dumps(values)}' for key, values in grid.items())]
    for point in points or []:
        lines += ["[[sweep.points]]", *(f'"{key}" = {json.dumps(value)}' for key, value in point.items())]
    path.write_text("\n".join(lines) + "\n")
    return path


def args(config, out, scheduler=None, force=False):
    return argparse.Namespace(config=str(config), out=str(out), scheduler=scheduler, force=force, debug=False)


def records(out):
    return {path.stem: json.loads(path.read_text()) for path in (Path(out) / "trials").glob("*.json")}


def expected(sweep):
    """Every trial's outcome, computed here without Dask: the independent truth."""
    return {t.id: fake_outcome(sweep.configs[t.point], t.decoder, t.condition, t.stimulation, t.index)
            for t in sweep.trials}


def command(*arguments):
    return [sys.executable, "-m", "rhi", "sweep", *map(str, arguments)]


def batched_file(path, checkpoints, grid=None, batch=None, workers=2, conditions=("left", "right"), trials=2):
    """A sweep of the default task at quick size: 30 steps of 0.1 s (touches at 2 s), the named decoders."""
    lines = ["[experiment]", 'decoders = ["conv", "vae"]', f"conditions = {json.dumps(list(conditions))}",
             "steps = 30", "step_size = 0.1", "[body]", "substeps = 40", "[decoder]",
             *(f'{kind}_checkpoint = "{checkpoint}"' for kind, checkpoint in checkpoints.items()),
             "[sweep]", "quick = true", f"trials = {trials}", f"workers = {workers}",
             *([f"batch = {batch}"] if batch else [])]
    if grid:
        lines += ["[sweep.grid]", *(f'"{key}" = {json.dumps(values)}' for key, values in grid.items())]
    path.write_text("\n".join(lines) + "\n")
    return path


def lockstep_truth(sweep) -> dict:
    """Every ok trial's drift, force and gamma from run_batch on its chunk's trials, here, on one core."""
    from rhi.master.tasks.illusion import make_trial, measures, run_batch
    from rhi.master.decoders.cache import checkpoint_path, decoder_component
    from rhi.master.tasks.illusion.measures import end_of_trial

    truth = {}
    for chunk in sweep.chunks:
        members = [sweep.trials[position] for position in chunk]
        config, kind = sweep.configs[members[0].point], members[0].decoder
        trials = [make_trial(config, t.decoder, t.condition, t.stimulation, t.index) for t in members]
        result = single_core(run_batch, decoder_component(kind, checkpoint_path(kind, config), config), trials,
                             config)
        final = end_of_trial(result.times, measures(result))
        for column, trial in enumerate(members):
            truth[trial.id] = {"drift_cm": float(final["drift_cm"][column]),
                               "force_n": float(final["force_x_n"][column]),
                               "gamma_final": float(final["gamma"][column])}
    return truth


def single_core(function, *arguments):
    """``function(*arguments)`` in this process on one core, like a sweep worker; then as before."""
    import torch

    cores, threads = os.sched_getaffinity(0), torch.get_num_threads()
    os.sched_setaffinity(0, {min(cores)})
    try:
        return function(*arguments)
    finally:
        os.sched_setaffinity(0, cores)
        torch.set_num_threads(threads)


def one_trial_sweep_folder(work):
    """A sweep folder of one trial, as rhi sweep prepares it before running, and the path of that trial's record:
    (the sweep, work/out/trials/ID.json, not written yet)."""
    from rhi.master.sweeps import plan as sweeps
    from rhi.master.sweeps.folder import sweep_folder

    sweep = sweeps.load(sweep_file(work / "s.toml", grid={"conditions.left": [-0.1]}, trials=1, conditions=("left",),
                                   workers=1))
    with sweep_folder(work / "out", sweep, False):
        pass
    return sweep, work / "out" / "trials" / f"{sweep.trials[0].id}.json"


@contextmanager
def dask_cluster_at(folder: Path, workers: int, env: dict | None = None):
    """A real `dask scheduler` and ``workers`` `dask worker` processes on 127.0.0.1 (ports the OS picks, logs and
    files in ``folder``, the environment ``env``, default ENV); yields the scheduler's address."""
    from dask.distributed import Client

    env = env or ENV
    log = open(folder / "cluster.log", "w")
    started = []

    def start(*arguments, core=None):
        pin = None if core is None else (lambda: os.sched_setaffinity(0, {core}))
        started.append(subprocess.Popen([str(DASK), *arguments], stdout=log, stderr=subprocess.STDOUT, env=env,
                                        cwd=folder, start_new_session=True, preexec_fn=pin))

    try:
        start("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
              "--scheduler-file", str(folder / "scheduler.json"))
        deadline = time.monotonic() + 60
        while not (folder / "scheduler.json").exists():
            assert time.monotonic() < deadline and started[0].poll() is None, "the dask scheduler did not start"
            time.sleep(0.1)
        address = json.loads((folder / "scheduler.json").read_text())["address"]
        # one core each, as sweep workers are meant to be: the decoder sizes torch's threads from the
        # process's cores, and two-thread processes on two busy cores run small convolutions ~30x slower
        cores = sorted(os.sched_getaffinity(0))
        for number in range(workers):
            start("worker", address, "--host", "127.0.0.1", "--nthreads", "1", "--no-nanny", "--no-dashboard",
                  "--name", f"w{number}", "--local-directory", str(folder), "--death-timeout", "60",
                  core=cores[number % len(cores)])
        with Client(address, timeout="30s") as client:
            client.wait_for_workers(workers, timeout=90)
        yield address
    finally:
        for group in (started[1:], started[:1]):  # workers first: they would wait for a lost scheduler
            for process in group:
                process.terminate()
            for process in group:
                try:
                    process.wait(timeout=10)
                except subprocess.TimeoutExpired:  # its own session: the group holds only what it started
                    os.killpg(process.pid, signal.SIGKILL)
                    process.wait()
        log.close()
