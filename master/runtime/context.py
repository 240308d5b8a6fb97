"""Run settings passed as one object, instead of a parameter of every function on the way."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RunContext:
    """How a run runs, not what it computes: none of these changes a number.

    Attributes
    ----------
    progress : bool
        Progress bars on standard error.
    force : bool
        Replace an output folder of rhi's that holds a different run.
    device : str
        Where the decoders train and run: ``"cpu"`` or ``"cuda"`` (resolved, not ``"auto"``).
    processes : int or None
        Most worker processes at once (default: the usable cores; 1: here, one after the other).
    scheduler : str or None
        A Dask scheduler's address for sweeps and fits (default: a process pool on this machine).
    debug : bool
        Failed trials' tracebacks printed, and errors raised with theirs (``rhi --debug``).
    """

    progress: bool = False
    force: bool = False
    device: str = "cpu"
    processes: int | None = None
    scheduler: str | None = None
    debug: bool = False

    def __post_init__(self):
        if self.scheduler is not None:
            check_scheduler_address(self.scheduler)

    @classmethod
    def of(cls, args, **settings) -> "RunContext":
        """The settings a command's parsed arguments give (``--force``, ``--scheduler``, ``--debug``, those it has),
        and ``settings`` (e.g. ``progress=True``, a resolved ``device``); ``rhi -q`` shows no progress."""
        if getattr(args, "verbosity", 0) < 0:
            settings = {**settings, "progress": False}
        return cls(force=getattr(args, "force", False), scheduler=getattr(args, "scheduler", None),
                   debug=getattr(args, "debug", False), **settings)


# The address forms a Dask client takes (distributed.comm.addressing): SCHEME://HOST:PORT, or HOST:PORT for tcp.
SCHEMES = ("tcp", "tls", "ucx", "ws", "wss")


def check_scheduler_address(address: str) -> None:
    """Refuse a Dask scheduler address that no client could use, before any work: a ConfigError naming it.

    Only its form is checked here (scheme, host, a port in 1..65535); whether a scheduler answers there is
    checked when the run connects (:func:`rhi.master.sweeps.runner.connect`)."""
    from rhi.master.cosim.errors import ConfigError

    scheme, _, location = address.rpartition("://")
    host, _, port = location.rpartition(":")
    if (scheme or "tcp") not in SCHEMES or not host.strip("[]") or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(f"--scheduler {address!r} is not a Dask scheduler address: give SCHEME://HOST:PORT "
                          f"(SCHEME one of {', '.join(SCHEMES)}), e.g. tcp://127.0.0.1:8786")
