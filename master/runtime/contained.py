"""A command run in a child process of its own, so that native code it loads (a ``--body`` FMU's binary) cannot
take rhi down with it: an ``abort()``, a segfault or an ``_exit()`` in the FMU ends the child, and the parent
says so in one line (exit status 1) and removes what the child left (its staging folder and lock beside DIR, its
temporary files), as ``rhi run-system`` does for its masters (rhi.master.export.system).

The child is ``python -m master ARGV`` with :data:`CHILD` set to a file it writes its exit status into just before
it returns (:func:`report_done`); a child that ends without writing it ended abnormally, whatever its status.
Its standard output and error are passed on as they come; Ctrl-C or SIGTERM given to the parent is passed to the
child (one signal: it cleans up and ends with 130 or 143), and the child dies with the parent
(rhi.master.outputs.processes.die_with_parent).
"""
from __future__ import annotations

import codecs
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

CHILD = "RHI_CONTAINED_STATUS"  # in the child's environment: where it reports its exit status
STOP_WAIT_S = 120  # how long an interrupted child may take to clean up before it is killed


def inside() -> bool:
    """Whether this process is such a child (it runs the command itself)."""
    return bool(os.environ.get(CHILD))


def report_done(status: int) -> None:
    """In a child: write its exit status where the parent looks for it (nothing elsewhere)."""
    where = os.environ.get(CHILD)
    if where:
        try:
            Path(where).write_text(f"{status}\n", encoding="ascii")
        except OSError:
            pass


def _relay(source, target, last: list) -> None:
    """Copy the child's stream ``source`` (a binary pipe) to ``target`` (this process's text stream) as it comes;
    ``last`` gets the last character written (a progress bar's line is not ended)."""
    decoder = codecs.getincrementaldecoder("utf-8")("replace")
    for chunk in iter(lambda: source.read1(65536), b""):
        text = decoder.decode(chunk)
        try:
            target.write(text)
            target.flush()
        except (OSError, ValueError):  # our own stream closed: the child's output has nowhere to go
            pass
        last[:] = text[-1:] or last
    source.close()


def run_child(argv: list[str], command: str, clean) -> int:
    """Run ``rhi ARGV`` in a child process and return its exit status; a child that ended abnormally (a signal,
    an ``_exit``) is one line naming how, status 1, after ``clean()`` removed what it left."""
    from rhi.master.outputs.processes import die_with_parent
    from rhi.master.outputs.scratch import scratch_folder

    with scratch_folder("rhi_contained_") as folder:
        done, scratch = folder / "status", folder / "tmp"
        scratch.mkdir()
        root = str(Path(__file__).resolve().parents[2])
        env = {**os.environ, CHILD: str(done), "TMPDIR": str(scratch),
               "PYTHONPATH": os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")]))}
        child = subprocess.Popen([sys.executable, "-m", "rhi", *argv], env=env, stdin=subprocess.DEVNULL,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                                 preexec_fn=die_with_parent)
        last = []  # stderr's last character
        relays = [threading.Thread(target=_relay, args=(stream, target, last if target is sys.stderr else []),
                                   daemon=True)
                  for stream, target in ((child.stdout, sys.stdout), (child.stderr, sys.stderr))]
        for relay in relays:
            relay.start()
        try:
            status = child.wait()
        except KeyboardInterrupt as interrupt:  # given to this process only (the child has a session of its own)
            from rhi.master.runtime.interrupts import Terminated

            child.send_signal(signal.SIGTERM if isinstance(interrupt, Terminated) else signal.SIGINT)
            try:
                status = child.wait(STOP_WAIT_S)
            except subprocess.TimeoutExpired:
                child.kill()
                status = child.wait()
        for relay in relays:
            relay.join()
        reported = done.is_file()
    if reported:
        return status
    clean()
    how = f"signal {signal.Signals(-status).name}" if status < 0 and -status in signal.valid_signals() else \
        f"status {status} without finishing"
    ended = "" if last in ([], ["\n"]) else "\n"  # after a progress bar's unfinished line
    print(f"{ended}rhi {command}: error: the simulation ended abnormally ({how}), in native code it loaded (the --body "
          "FMU's binary); nothing was written", file=sys.stderr, flush=True)
    return 1


def clean_output(out) -> None:
    """Remove what a child that ended abnormally left beside DIR = ``out``: its staging folder and its lock (once
    no run holds the lock; another run's are never touched)."""
    from rhi.master.cosim import ConfigError
    from rhi.master.outputs.files import OutputLock, clean_stale

    try:
        lock = OutputLock(Path(out)).acquire()
    except ConfigError:  # another run holds DIR now: what it left is its own to clean
        return
    try:
        clean_stale(Path(out))
    finally:
        lock.release()
