"""Time limits and signals during calls into an FMU: :class:`Watch` (one per process, :data:`WATCH`)."""
from __future__ import annotations

import os
import signal
import sys
import threading
import time

class CallStopped(Exception):
    """Raised inside a call into an FMU (a pythonfmu slave runs Python in the calling thread) to end it:
    it is over its time limit, or the process received SIGINT or SIGTERM. The FMU fails the call."""


def _default_on_stuck(message: str) -> None:
    sys.stderr.write(message + "\n")
    sys.stderr.flush()
    os._exit(1)


# Called (from the watchdog thread) with a one-line message when a call has not returned long after its
# limit and cannot be stopped (it runs native code that never returns to Python); it must end the
# process. The command line replaces it to remove its staging folder first.
on_stuck = _default_on_stuck


def _grace(limit: float) -> float:
    """Seconds past the limit before a call that ignores being stopped counts as stuck for good."""
    return min(max(limit, 2.0), 10.0)


class Call:
    """One component's calls into its FMU instances, under way in the main thread (at most one at a time)."""

    __slots__ = ("label", "what", "t", "trial", "limit", "started", "inside", "overdue", "signal", "next_kick")

    def __init__(self, label: str, what: str, t: float, limit: float | None):
        self.label, self.what, self.t, self.limit = label, what, t, limit
        self.trial, self.started, self.inside, self.overdue, self.signal, self.next_kick = 0, 0.0, False, False, None, 0.0


class Watch:
    """SIGINT, SIGTERM and SIGALRM handlers (main thread) and one watchdog thread, for FMU calls.

    While a call is inside the FMU, SIGINT/SIGTERM raise CallStopped there (so the FMU fails the call
    cleanly, as with any exception of its own) and are remembered; the adapter takes them up when the
    call has returned. Outside a call they go to the handlers that were there before. The watchdog
    thread sends SIGALRM to the main thread when a call passes its limit (again every second), which
    raises CallStopped inside it; a call still running ``_grace`` seconds later is stuck in native code,
    and ``on_stuck`` ends the process. Calls from other threads get only the watchdog's last resort.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self.users = 0
        self.previous: dict[int, object] = {}
        self.calls: dict[int, Call] = {}  # thread ident -> its call in progress
        self.thread = None

    # handlers: installed while any FMUComponent is instantiated in the main thread
    def attach(self) -> None:
        """Count one more user; the first installs the SIGINT, SIGTERM and SIGALRM handlers. Outside the main thread:
        nothing.
        """
        if threading.current_thread() is not threading.main_thread():
            return
        if self.users == 0:
            for number in (*self.SIGNALS, signal.SIGALRM):
                previous = signal.getsignal(number)
                self.previous[number] = signal.SIG_DFL if previous is None else previous
                signal.signal(number, self._on_signal)
        self.users += 1

    def detach(self) -> None:
        """Count one user fewer; the last puts back the handlers that were there before. Outside the main thread:
        nothing.
        """
        if threading.current_thread() is not threading.main_thread() or self.users == 0:
            return
        self.users -= 1
        if self.users == 0:
            for number, previous in self.previous.items():
                if signal.getsignal(number) == self._on_signal:
                    signal.signal(number, previous)
            self.previous.clear()

    def _on_signal(self, number, frame):
        call = self.calls.get(threading.main_thread().ident)
        if number == signal.SIGALRM:
            if call is not None and call.inside and call.overdue:
                raise CallStopped(f"over the time limit of {call.limit:g} s")
            return self._pass_on(number, frame)
        if call is not None and call.inside:
            call.signal = number
            raise CallStopped(f"interrupted by {signal.Signals(number).name}")
        return self._pass_on(number, frame)

    def _pass_on(self, number, frame):
        """What the signal would have done without us."""
        previous = self.previous.get(number, signal.SIG_DFL)
        if callable(previous):
            return previous(number, frame)
        if previous == signal.SIG_IGN or number == signal.SIGALRM:
            return None
        signal.signal(number, signal.SIG_DFL)  # the default action (ends the process)
        signal.raise_signal(number)

    def deliver(self, number: int) -> None:
        """Take up a signal that arrived during a call, now that the call has returned."""
        self._pass_on(number, None)

    # the calls, and the watchdog thread
    def begin(self, call: Call) -> None:
        """``call`` is under way in this thread; the watchdog thread starts if the call has a limit and none runs."""
        self.calls[threading.get_ident()] = call
        if call.limit and (self.thread is None or not self.thread.is_alive()):
            self.thread = threading.Thread(target=self._watch, name="rhi-fmu-watchdog", daemon=True)
            self.thread.start()

    def end(self) -> None:
        """This thread's call is over."""
        self.calls.pop(threading.get_ident(), None)

    def _watch(self) -> None:
        main = threading.main_thread().ident
        idle_since = time.monotonic()
        while True:
            time.sleep(0.05)
            now = time.monotonic()
            calls = list(self.calls.items())
            if not calls:
                if now - idle_since > 5.0:  # started again by the next call that has a limit
                    self.thread = None
                    return
                continue
            idle_since = now
            for ident, call in calls:
                if not call.limit or not call.inside:
                    continue
                over = now - call.started - call.limit
                if over < 0:
                    continue
                call.overdue = True
                if over > _grace(call.limit):
                    on_stuck(f"{call.label}: {call.what} in trial {call.trial} at t = {call.t:.6g} s has not "
                             f"returned after {now - call.started:.0f} s (time limit {call.limit:g} s) and cannot "
                             "be stopped (it runs native code that does not return); ending the process")
                elif ident == main and now >= call.next_kick and self.users:
                    call.next_kick = now + 1.0
                    signal.pthread_kill(main, signal.SIGALRM)


WATCH = Watch()
