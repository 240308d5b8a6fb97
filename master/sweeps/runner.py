"""Running a sweep's chunks on a dask.distributed Client: a local process pool or a remote cluster.

Each chunk of the plan is one task: with the experiment's own trial function, its trials in one
lockstep batch (:func:`run_chunk`); with any other, one trial (:func:`run_trial`). Each trial's record
is written to ``out/trials/ID.json`` the moment its chunk arrives, on the client's machine, so the
workers need no shared folder. A failing trial is a record, not a crash.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import importlib
import json
import logging
import os
import threading
import socket
import time
import traceback
import uuid
from contextlib import contextmanager
from pathlib import Path

from rhi.master.cosim import ConfigError
from rhi.master.tasks.illusion.runner import failed_record
from rhi.master.outputs.files import atomic_write
from rhi.master.sweeps import lifeline
from rhi.master.sweeps.folder import record_problem
from rhi.master.sweeps.plan import DEFAULT_TASK, Sweep, TrialSpec, is_task, task_location

log = logging.getLogger("rhi.sweep")

# Dask's settings for workers whose tasks are long, single-threaded and CPU-bound (docs/sweeps.md): no
# statistical profiler (by default it takes the GIL every 10 ms to walk the running task's stack), and
# the event loop's health check and the monitors at a pace that such tasks do not notice. The local
# pool's workers get them; a cluster's workers take them as environment variables (docs/sweeps.md).
WORKER_SETTINGS = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.worker.memory.monitor-interval": "1s",
}

# glibc's mallopt parameters, and the thresholds its dynamic mode reaches at most on a 64-bit machine
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD = 32 * 1024 * 1024   # bytes: a block this large or larger is mapped for itself
TRIM_THRESHOLD = 2 * MMAP_THRESHOLD  # bytes: free memory at the heap's top kept for reuse


@contextmanager
def dask_client(scheduler: str | None, workers: int | None, debug: bool):
    """A Client on the given scheduler, or on a local pool of single-threaded worker processes with
    :data:`WORKER_SETTINGS`."""
    import dask
    from dask.distributed import Client, LocalCluster

    if scheduler:
        with connect(Client, scheduler) as client:
            yield client
        return
    # Not ERROR: a worker's heartbeat that races the pool's own shutdown logs one, with a traceback; a trial's
    # failure reaches the caller through its future and is reported there.
    from rhi.master.runtime.pool import may_spawn

    if not may_spawn():  # its nannies would import an unguarded __main__ again, and the cluster never start
        raise ConfigError("a local Dask cluster cannot start from here (a script without an "
                          "`if __name__ == \"__main__\":` guard, or a worker process): put the script's work under "
                          "such a guard, or give a running scheduler's address")
    quiet = False if debug else logging.CRITICAL
    # Only this machine: listen on loopback; the scheduler's small HTTP server on any free port. The
    # nannies hand the settings in force when they start to their workers.
    # Each worker dies with this process, even by SIGKILL (rhi.master.sweeps.lifeline, a worker preload).
    with dask.config.set({**WORKER_SETTINGS, lifeline.PARENT_KEY: os.getpid()}), \
            LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                         host="127.0.0.1", dashboard_address=None, silence_logs=quiet, preload=[lifeline.__name__],
                         scheduler_kwargs={"dashboard_address": "127.0.0.1:0"}) as cluster, Client(cluster) as client:
        yield client


CONNECT_TIMEOUT_S = 15.0  # --scheduler: a scheduler that has not answered by then is refused


PROBE_S = 3.0  # of CONNECT_TIMEOUT_S: how long the probe waits for a tcp:// scheduler's first bytes
# A Dask listener speaks first on a new connection: its handshake, 8 bytes (little-endian uint64: the bytes
# to follow) and a small msgpack message (a few hundred bytes). Dask allocates what those 8 bytes announce.
MAX_HANDSHAKE_BYTES = 2**20


# What the probe says to a listener that stays silent: a frame as Dask's TCP comm frames one (8 bytes, the
# little-endian length of what follows, then 2 bytes), ending a line: an HTTP server answers it (400, bad request),
# a Dask scheduler (which would have spoken first) reads a 2-byte message it cannot decode and drops it.
POKE = (2).to_bytes(8, "little") + b"\r\n"


def probe(scheduler: str, timeout: float) -> str | None:
    """Why the tcp:// listener at ``scheduler`` is not a Dask scheduler, from the first bytes it sends (within
    half of ``timeout``), or, if it stays silent, those it answers to :data:`POKE` (within the other half): an
    HTTP server's answer, or a first message larger than MAX_HANDSHAKE_BYTES (which dask would try to
    allocate). None when it looks like one, sends nothing, or cannot be reached (dask's own attempt then says
    why)."""
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, location = parse_address(scheduler)
        if scheme != "tcp":
            return None
        host, port = parse_host_port(location)
        with socket.create_connection((host, port), timeout=timeout / 2) as peer:
            peer.settimeout(timeout / 2)
            try:
                head = peer.recv(8, socket.MSG_WAITALL)
            except TimeoutError:  # silent: a Dask scheduler speaks first; what does it answer when spoken to?
                peer.sendall(POKE)
                head = peer.recv(8, socket.MSG_WAITALL)
    except (OSError, ValueError, TypeError):
        return None
    if head.startswith(b"HTTP/") or head[:4].upper() in (b"<!DO", b"<HTM"):
        return "it answers HTTP: a web server (a Dask dashboard?), not a Dask scheduler's port"
    if len(head) == 8 and int.from_bytes(head, "little") > MAX_HANDSHAKE_BYTES:
        return (f"it does not speak Dask's protocol (its first message would be {int.from_bytes(head, 'little')} "
                f"bytes; a Dask handshake is under {MAX_HANDSHAKE_BYTES})")
    return None


def connect(client_class, scheduler: str):
    """A Client on ``scheduler``, or a ConfigError within CONNECT_TIMEOUT_S seconds naming why: refused,
    not a Dask scheduler (a listener that never answers, an HTTP server: :func:`probe`), a scheme dask cannot
    use. The attempt runs in a daemon thread, since dask's own timeout does not cover a peer that stays silent."""
    began = time.monotonic()
    problem = probe(scheduler, PROBE_S)
    if problem:
        raise ConfigError(f"cannot reach the Dask scheduler at {scheduler}: {problem}")
    outcome = {}

    def attempt():
        try:
            outcome["client"] = client_class(scheduler, timeout=f"{CONNECT_TIMEOUT_S - PROBE_S - 3:g}s")
        except BaseException as error:  # noqa: BLE001: reported below, in one line
            outcome["error"] = error

    thread = threading.Thread(target=attempt, name="rhi-dask-connect", daemon=True)
    thread.start()
    thread.join(max(CONNECT_TIMEOUT_S - (time.monotonic() - began), 1.0))
    if "client" in outcome:
        return outcome["client"]
    error = outcome.get("error")
    reason = (" ".join(f"{type(error).__name__}: {error}".split())[:200] if error is not None
              else f"no Dask scheduler answered within {CONNECT_TIMEOUT_S:g} s")
    raise ConfigError(f"cannot reach the Dask scheduler at {scheduler}: {reason}")


def check_workers(client, task: str) -> None:
    """Every connected worker must import the task's module (this package, installed there); one note on
    stderr names the :data:`WORKER_SETTINGS` that some workers lack."""
    if not client.scheduler_info().get("workers"):
        log.info(f"rhi sweep: waiting for a Dask worker to connect to {client.scheduler.address}")
        client.wait_for_workers(1)
    module = task_location(task).partition(":")[0]
    answers = client.run(worker_check, module, on_error="return")
    for worker, answer in answers.items():
        if isinstance(answer, BaseException):
            raise ConfigError(f"Dask worker {worker} cannot import {module} ({answer}); "
                              "install this package on every worker (see docs/sweeps.md)")
    unset = sorted({key for answer in answers.values() for key in answer})
    if unset:
        log.warning(f"rhi sweep: note: {sum(map(bool, answers.values()))} of {len(answers)} Dask workers lack the "
                    f"settings for long CPU-bound tasks ({', '.join(unset)}), which slows the trials; docs/sweeps.md "
                    "shows how to start them")


def check_decoders(sweep: Sweep) -> None:
    """Before the sweep starts: every point's decoders (checkpoints named, or training settings and cache),
    for the experiment's own trial function and a task's; a ConfigError naming the point otherwise."""
    if sweep.task != DEFAULT_TASK and not is_task(sweep.task):
        return
    from rhi.master.decoders.cache import check_decoders as check

    from rhi.master.sweeps.plan import describe
    for number, config in enumerate(sweep.configs):
        try:
            check(config)
        except (ConfigError, ValueError) as error:  # ValueError: a CheckpointError (ComponentError)
            raise ConfigError(f"sweep point {number} ({describe(sweep.points[number])}): {error}") from None


def prepare_decoders(sweep: Sweep) -> None:
    """The experiment's trials load trained decoders; train any missing default here, once, never on
    the workers (a remote worker must see the same checkpoint paths, see docs/sweeps.md)."""
    if sweep.task != DEFAULT_TASK and not is_task(sweep.task):
        return
    from rhi.master.decoders.cache import ensure_checkpoints

    for config in sweep.configs:  # a checkpoint already there is not trained again
        ensure_checkpoints(config)


def steady_malloc() -> None:
    """Keep the large temporaries of a step on the heap for the next step, as glibc does after warm-up in a
    plain process; a no-op where the C library has no ``mallopt``.

    Dask's nanny starts its workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which turns glibc's dynamic
    thresholds off: every array above 128 KiB a step frees goes back to the system, and the next step
    faults its pages in again (docs/sweeps.md). Idempotent; called by every task, so that a worker that
    joins during the sweep gets it too.
    """
    try:
        mallopt = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").mallopt
    except (OSError, AttributeError):
        return
    mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)
    mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD)


def run_trial(task, config: dict, trial: TrialSpec) -> dict:
    """Runs on a worker. Never raises: a failure is a record with its error, so the rest continue."""
    steady_malloc()
    started, began = time.time(), time.perf_counter()
    try:
        outcome = task(config, trial.decoder, trial.condition, trial.stimulation, trial.index)
        record = {"status": "ok", "outcome": {key: plain(value) for key, value in outcome.items()}}
        problem = record_problem(record, default_task=False)  # as it is read back: measures that are numbers
        if problem:
            raise TypeError(f"the task's outcome is not one a sweep can table: {problem}")
    except Exception as error:  # noqa: BLE001: any failure of a trial is data, not a crash
        record = failed_record(type(error).__name__, str(error), traceback.format_exc())
    record.update(elapsed_s=round(time.perf_counter() - began, 6), host=socket.gethostname(),
                  started_at=round(started, 3), batch=1)
    return record


def run_chunk(config: dict, trials: list[TrialSpec], configs: list[dict] | None = None) -> list[dict]:
    """Runs on a worker: the chunk's trials (one point, or with ``configs`` each trial's point's configuration,
    one decoder) in one lockstep batch, each failure isolated to its trial
    (:func:`rhi.master.tasks.illusion.runner.batch_outcomes`); one result per trial, in order. Never raises.
    ``elapsed_s`` is the whole chunk's time, the worker's one-time imports excluded (as the experiment's
    batches count theirs)."""
    from rhi.master.tasks.illusion import make_trial
    from rhi.master.tasks.illusion.runner import batch_outcomes
    from rhi.master.config.sources import batchable_keys

    importlib.import_module("rhi.master.decoders.cache")  # torch: once per worker, before the clock starts

    steady_malloc()
    started, began, cpu = time.time(), time.perf_counter(), time.process_time()
    try:
        own = [()] * len(trials)
        if configs is not None:  # several points in one batch: each trial carries its point's parameter values
            keys = sorted(batchable_keys(config))
            own = [tuple((key, mine[key.split(".")[0]][key.split(".")[1]]) for key in keys) for mine in configs]
        protocol = [make_trial(mine, t.decoder, t.condition, t.stimulation, t.index, overrides)
                    for t, mine, overrides in zip(trials, configs or [config] * len(trials), own)]
        results = batch_outcomes(config, trials[0].decoder, protocol)
    except Exception as error:  # noqa: BLE001: batch_outcomes isolates failures; this is the last resort
        results = [failed_record(type(error).__name__, str(error), traceback.format_exc())] * len(trials)
    timing = {"elapsed_s": round(time.perf_counter() - began, 6), "cpu_s": round(time.process_time() - cpu, 6),
              "host": socket.gethostname(), "started_at": round(started, 3), "batch": len(trials)}
    return [{**result, **timing} for result in results]


def plain(value):
    """numpy scalars and arrays -> Python numbers and lists, so the record is plain JSON."""
    return value.tolist() if hasattr(value, "tolist") else value


def worker_check(module: str) -> list[str]:
    """Runs on each worker before the sweep: imports the task's module (ImportError if it cannot), and
    returns the keys of :data:`WORKER_SETTINGS` whose value this worker's Dask configuration does not have."""
    import dask
    from dask.utils import parse_timedelta

    importlib.import_module(module)

    def same(value, wanted):
        if isinstance(wanted, str) and isinstance(value, str):  # durations: "1s" is "1000ms"
            return parse_timedelta(value) == parse_timedelta(wanted)
        return value == wanted

    return [key for key, wanted in WORKER_SETTINGS.items() if not same(dask.config.get(key, None), wanted)]


def run_in_memory(sweep: Sweep) -> dict[str, dict]:
    """Every trial of a batched sweep run here, chunk by chunk as :func:`execute` submits them (so each trial gets
    the numbers a sweep folder holds), nothing written: ``{trial id: record}``."""
    records = {}
    for chunk in sweep.chunks:
        members = [sweep.trials[position] for position in chunk]
        several = None if len({t.point for t in members}) == 1 else [sweep.configs[t.point] for t in members]
        for trial, result in zip(members, run_chunk(sweep.configs[members[0].point], members, several)):
            records[trial.id] = {"id": trial.id, "point": trial.point, **result}
    return records


def execute(sweep: Sweep, task, client, out: Path, done: set[str], on_record=None) -> list[dict]:
    """Submit every chunk with a trial not in ``done``; write each of its trials' records not in ``done``
    to ``out/trials/ID.json`` as the chunk arrives.

    A chunk is always run whole, so its trials get the numbers an uninterrupted sweep gives them; the
    records already done are left as they are. ``on_record(record)`` is called after each write
    (progress, index). Returns the new records.
    """
    from dask.distributed import as_completed

    pending, token = {}, uuid.uuid4().hex[:8]
    for chunk in sweep.chunks:
        members = [sweep.trials[position] for position in chunk]
        if all(trial.id in done for trial in members):
            continue
        config = sweep.configs[members[0].point]
        if sweep.batched:
            several = None if len({t.point for t in members}) == 1 else [sweep.configs[t.point] for t in members]
            future = client.submit(run_chunk, config, members, several, pure=False,
                                   key=f"rhi-chunk-{members[0].id}-{token}")
        else:
            future = client.submit(run_trial, task, config, members[0], pure=False,
                                   key=f"rhi-trial-{members[0].id}-{token}")
        pending[future] = members
    records = []
    for future in as_completed(list(pending)):
        members = pending.pop(future)
        try:
            results = future.result() if sweep.batched else [future.result()]
        except Exception as error:  # noqa: BLE001: a lost worker or an unpicklable task fails its chunk's trials
            results = [failed_record(type(error).__name__, str(error))] * len(members)
        for trial, result in zip(members, results):
            if trial.id in done:
                continue
            record = {"id": trial.id, "point": trial.point, "parameters": sweep.points[trial.point],
                      "decoder": trial.decoder, "condition": trial.condition, "stimulation": trial.stimulation,
                      "trial": trial.index, "seed": trial.seed, **result}
            atomic_write(out / "trials" / f"{trial.id}.json", json.dumps(record, indent=1, sort_keys=True) + "\n")
            records.append(record)
            if on_record is not None:
                on_record(record)
        future.release()
    return records
