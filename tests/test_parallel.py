"""rhi.master.runtime.pool: jobs side by side in spawned processes give what they give one after the other."""
import errno

import pytest

from rhi.master.cosim import SimulationError
from rhi.master.runtime import pool as parallel


def job(seed: int, fail: bool | str = False):
    """A job whose numbers use torch (threads, BLAS): a matrix product seeded per job."""
    import errno

    import torch

    if fail == "disk":
        raise OSError(errno.ENOSPC, "No space left on device", "out/trials.csv")
    if fail:
        raise SimulationError("body", 0.5, "NaN in q", trials=(1,))
    generator = torch.Generator().manual_seed(seed)
    a = torch.randn(64, 64, generator=generator, dtype=torch.float64)
    return seed, torch.get_num_threads(), (a @ a.T @ a).sum().item()


def test_jobs_in_processes_equal_jobs_here_in_order():
    jobs = [(seed,) for seed in (3, 1, 2)]
    here = parallel.run_jobs(job, jobs, processes=1)
    side_by_side = parallel.run_jobs(job, jobs, processes=2)
    assert [result[0] for result in side_by_side] == [3, 1, 2]       # the order of the jobs
    assert all(result[1] == parallel.JOB_THREADS for result in side_by_side + here)  # one torch thread each
    assert side_by_side == here                                      # bit for bit


def test_a_job_s_error_reaches_the_caller_whole():
    with pytest.raises(SimulationError) as raised:
        parallel.run_jobs(job, [(1,), (2, True)], processes=2)
    assert raised.value.trials == (1,) and raised.value.component == "body" and raised.value.time == 0.5
    assert str(raised.value) == str(SimulationError("body", 0.5, "NaN in q", trials=(1,)))
    with pytest.raises(OSError) as raised:  # a file a worker could not write
        parallel.run_jobs(job, [(1,), (2, "disk")], processes=2)
    assert (raised.value.errno, raised.value.filename) == (errno.ENOSPC, "out/trials.csv")


def pid(offset: int = 0) -> int:
    import os

    return os.getpid() + offset


def test_workers_keep_their_processes_across_rounds_and_call_runs_mixed_jobs():
    import os

    with parallel.Workers(2) as workers:
        first = workers.map(pid, [(), ()])
        mixed = workers.map(parallel.call, [(pid, 0), (job, 5), (pid, 0)])
        assert os.getpid() not in first
        assert set(first) | {mixed[0], mixed[2]} <= set(workers._pool._pool[i].pid for i in range(2))
        assert mixed[1] == parallel.run_jobs(job, [(5,)], processes=1)[0]
        with pytest.raises(SimulationError):
            workers.map(job, [(1,), (2, True)])
        assert workers._pool is None                # terminated on the error
        assert workers.map(job, [(4,), (6,)]) == parallel.run_jobs(job, [(4,), (6,)], processes=1)  # new workers
    assert workers._pool is None


def test_one_process_runs_the_jobs_here():
    import os

    with parallel.Workers(1) as workers:
        assert workers.map(pid, [(), ()]) == [os.getpid()] * 2 and workers._pool is None


def test_light_jobs_start_no_workers_but_use_those_started():
    import os

    with parallel.Workers(2) as workers:
        assert workers.map(pid, [(), ()], start=False) == [os.getpid()] * 2 and workers._pool is None
        started = set(workers.map(pid, [(), ()]))
        light = workers.map(pid, [(), ()], start=False)
        assert os.getpid() not in light and set(light) <= set(workers._pool._pool[i].pid for i in range(2))
        assert os.getpid() not in started
