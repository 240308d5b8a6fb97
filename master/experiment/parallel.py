"""Independent jobs on this machine's cores: one fresh process per job at a time, results in order.

A job's numbers must not depend on the schedule. So each job runs in a spawned process (nothing
inherited from the parent's torch or OpenMP state) with one torch thread, whichever job runs beside
it; with a single job, or a single usable core, the jobs run here in turn with one torch thread too,
and give the same bytes. A job that builds a component which sets torch's threads itself (a
decoder) gives it ``JOB_THREADS``. An interruption (Ctrl-C, SIGTERM) terminates the workers at once.

Example::

    results = run_jobs(train_one, [("conv",), ("vae",)])   # [train_one("conv"), train_one("vae")]
"""
from __future__ import annotations

import multiprocessing
import os
import signal

JOB_THREADS = 1  # torch threads per job; the parallelism is across jobs


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def process_count(jobs: int, processes: int | None = None) -> int:
    """How many processes :func:`run_jobs` uses for ``jobs`` jobs (1: none, the jobs run here)."""
    return max(1, min(processes or usable_cores(), jobs))


def _start_worker() -> None:
    """A worker leaves Ctrl-C to the parent (which terminates it) and uses one torch thread, whose OpenMP
    waits yield the core (as `rhi` sets for itself, master.commands.cli) rather than spin."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    import torch

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    torch.set_num_threads(JOB_THREADS)


def run_jobs(function, jobs: list[tuple], processes: int | None = None) -> list:
    """``[function(*job) for job in jobs]``, up to ``processes`` at a time (default: the usable cores).

    Parameters
    ----------
    function : callable
        A module-level function (workers import it by name); its arguments, result and exceptions
        must pickle (an exception that does not unpickle would leave the pool waiting).
    jobs : list of tuple
        The arguments of each call.
    processes : int, optional
        Most worker processes at once; 1 runs the jobs here, in this process.

    Returns
    -------
    list
        Each job's result, in the order of ``jobs``. A job's exception is raised here.
    """
    if process_count(len(jobs), processes) <= 1:
        import torch

        threads = torch.get_num_threads()
        torch.set_num_threads(JOB_THREADS)
        try:
            return [function(*job) for job in jobs]
        finally:
            torch.set_num_threads(threads)
    pool = multiprocessing.get_context("spawn").Pool(process_count(len(jobs), processes), initializer=_start_worker)
    try:
        pending = [pool.apply_async(function, job) for job in jobs]
        results = [result.get() for result in pending]
        pool.close()
        return results
    except BaseException:  # a job's error, Ctrl-C or SIGTERM: stop the other jobs now
        pool.terminate()
        raise
    finally:
        pool.join()
