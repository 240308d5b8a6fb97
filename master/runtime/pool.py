"""Independent jobs on this machine's cores: worker processes, results in order.

A job's numbers must not depend on the schedule. So each job runs in a spawned worker (nothing
inherited from the parent's torch or OpenMP state) with one torch thread, whichever job runs beside
it; with a single job, or a single usable core, the jobs run here in turn with one torch thread too,
and give the same bytes. A job that builds a component which sets torch's threads itself (a
decoder) gives it ``JOB_THREADS``. An interruption (Ctrl-C, SIGTERM) terminates the workers at once.

:class:`Workers` keeps its processes for several rounds of jobs (a run's trials, then its files), so
that each worker imports torch once; :func:`run_jobs` is one round on workers of its own.

Example::

    results = run_jobs(train_one, [("conv",), ("vae",)])   # [train_one("conv"), train_one("vae")]
    with Workers() as workers:
        trained = workers.map(train_one, [("conv",), ("vae",)])
        written = workers.map(call, [(write_table, rows), (write_figure, data)])
"""
from __future__ import annotations

import ast
import logging
import multiprocessing
import os
import signal
import sys

JOB_THREADS = 1  # torch threads per job; the parallelism is across jobs


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


# Worker processes of a local pool (sweep.workers, fit.workers): each is a single-threaded process that imports
# torch and holds a decoder (a few hundred MB), so workers beyond the cores add memory, not speed; four per core
# leaves room for workers that wait (on a file, on the scheduler) and refuses a count that would fill the memory.
WORKERS_PER_CORE = 4


def max_workers() -> int:
    """The most local worker processes a sweep or a fit may ask for: :data:`WORKERS_PER_CORE` x the usable cores."""
    return WORKERS_PER_CORE * usable_cores()


def workers_problem(key: str, value) -> str | None:
    """Why ``value`` is not a worker count ``key`` may ask for (a whole number from 1 to :func:`max_workers`)."""
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        return f"{key} must be a whole number of at least 1, got {value!r}"
    if value > max_workers():
        return (f"{key} = {value} is over the limit of {max_workers()} ({WORKERS_PER_CORE} x this machine's "
                f"{usable_cores()} usable cores): each worker is a process holding torch and a decoder, and "
                "workers beyond the cores add memory, not speed")
    return None


def process_count(jobs: int, processes: int | None = None) -> int:
    """How many processes run ``jobs`` jobs at once, at most ``processes`` (default: the usable cores);
    1: none, the jobs run here."""
    return max(1, min(processes or usable_cores(), jobs))


def main_module_guarded() -> bool:
    """Whether a spawned process may import this program's ``__main__`` without running it again: true for an
    interactive session, a notebook, ``python -c`` or ``-m rhi`` (nothing of the user's to re-import), and for a
    script whose top level runs its work under ``if __name__ == "__main__":``; false for a script with no such
    guard, which each spawned worker would run again from the top (multiprocessing's "safe importing of main
    module" rule), so that a pool started from it would never finish."""
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if path is None or (getattr(main, "__spec__", None) is not None
                        and main.__spec__.name.partition(".")[0] == "rhi"):
        return True
    try:
        tree = ast.parse(open(path, encoding="utf-8").read())
    except (OSError, SyntaxError, ValueError):
        return False
    return any(isinstance(node, ast.If) and "__main__" in ast.unparse(node.test) and "__name__" in ast.unparse(node.test)
               for node in tree.body)


def may_spawn() -> bool:
    """Whether worker processes may start here: not in a spawned worker or a daemon process (a Dask worker, a
    pool's worker), and not from an unguarded script (:func:`main_module_guarded`)."""
    here = multiprocessing.current_process()
    return not here.daemon and multiprocessing.parent_process() is None and main_module_guarded()


_WARNED = []


def _run_here_instead() -> None:
    if not _WARNED:
        _WARNED.append(True)
        logging.getLogger("rhi").info(
            "rhi: running the jobs in this process, one after the other: worker processes cannot start here (a "
            "script without an `if __name__ == \"__main__\":` guard, or a worker process); put the script's work "
            "under such a guard to use every core")


def call(function, *arguments):
    """``function(*arguments)``: a job for rounds whose jobs call different functions."""
    return function(*arguments)


def _start_worker() -> None:
    """A worker leaves Ctrl-C to the parent (which terminates it) and uses one torch thread, whose OpenMP
    waits yield the core (as `rhi` sets for itself, rhi.master.commands.cli) rather than spin."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    import torch

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    torch.set_num_threads(JOB_THREADS)


class Workers:
    """Up to ``processes`` spawned worker processes (default: the usable cores), kept across rounds of jobs.

    Verbs: :meth:`map` (one round; the workers start at the first round that needs more than one process),
    :meth:`close`. As a context manager it closes on leaving, and terminates the workers at once on an
    error, Ctrl-C or SIGTERM.
    """

    def __init__(self, processes: int | None = None):
        self.processes = max(1, processes or usable_cores())
        self._pool = None

    def map(self, function, jobs: list[tuple], start: bool = True) -> list:
        """``[function(*job) for job in jobs]``, up to ``processes`` at a time; here, in turn, when only one
        would run at a time, or when ``start`` is false and no earlier round started the workers (for light
        jobs, such as a run's files: starting a worker, which imports torch, costs more than they do).

        Parameters
        ----------
        function : callable
            A module-level function (workers import it by name); its arguments, result and exceptions
            must pickle (an exception that does not unpickle would leave the pool waiting).
        jobs : list of tuple
            The arguments of each call.

        Returns
        -------
        list
            Each job's result, in the order of ``jobs``. A job's exception is raised here (and the
            workers are terminated).
        """
        here = process_count(len(jobs), self.processes) <= 1 or (not start and self._pool is None)
        if not here and self._pool is None and not may_spawn():
            _run_here_instead()
            here = True
        if here:
            import torch

            threads = torch.get_num_threads()
            torch.set_num_threads(JOB_THREADS)
            try:
                return [function(*job) for job in jobs]
            finally:
                torch.set_num_threads(threads)
        if self._pool is None:
            self._pool = multiprocessing.get_context("spawn").Pool(self.processes, initializer=_start_worker)
        try:
            pending = [self._pool.apply_async(function, job) for job in jobs]
            return [result.get() for result in pending]
        except BaseException:  # a job's error, Ctrl-C or SIGTERM: stop the other jobs now
            self.close(terminate=True)
            raise

    def close(self, terminate: bool = False) -> None:
        """Let the workers finish (or ``terminate`` them) and wait for them; a later round starts new ones."""
        if self._pool is not None:
            pool, self._pool = self._pool, None
            pool.terminate() if terminate else pool.close()
            pool.join()

    def __enter__(self) -> "Workers":
        return self

    def __exit__(self, kind, error, traceback) -> None:
        self.close(terminate=kind is not None)


def run_jobs(function, jobs: list[tuple], processes: int | None = None, workers: Workers | None = None) -> list:
    """:meth:`Workers.map` on ``workers`` (left open) when given, else on up to ``processes`` workers of its
    own, closed when the jobs are done."""
    if workers is not None:
        return workers.map(function, jobs)
    with Workers(process_count(len(jobs), processes)) as own:
        return own.map(function, jobs)
