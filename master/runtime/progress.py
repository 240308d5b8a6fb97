"""Progress bars that suit where standard error goes: tqdm's redrawn bar on a terminal (or in a notebook), and
one whole line every few seconds anywhere else, so that a log file of a run holds no carriage returns and no
overwritten bars."""
from __future__ import annotations

import logging
import sys

LINE_EVERY_S = 5.0  # off a terminal: at most one line per bar this often (tqdm's mininterval)


def interactive(stream=None) -> bool:
    """Whether ``stream`` (default: standard error) redraws a line: a terminal, or a Jupyter kernel's stream."""
    stream = sys.stderr if stream is None else stream
    if type(stream).__module__.startswith("ipykernel"):
        return True
    try:
        return stream.isatty()
    except (AttributeError, ValueError, OSError):  # closed, or no such method
        return False


class Lines:
    """A file for tqdm that writes each state of a bar as one line of ``stream``, never a carriage return."""

    def __init__(self, stream):
        self.stream = stream

    def write(self, text: str) -> None:
        """Each non-blank line of ``text`` (tqdm's ``\r``-led redraws split at them) as a line of its own."""
        for line in text.replace("\r", "\n").splitlines():
            if line.strip():
                self.stream.write(line.rstrip() + "\n")

    def flush(self) -> None:
        """Flush the stream."""
        self.stream.flush()


def quiet() -> bool:
    """Whether the ``rhi`` logger was set above INFO (``rhi -q``): no bar then. Its level unset (a script, a
    notebook, a worker process), bars are shown where the caller asks for them."""
    return logging.getLogger("rhi").level > logging.INFO


def bar(iterable=None, **options):
    """A tqdm bar on standard error (``options`` as tqdm's); off a terminal, a line per state at most every
    :data:`LINE_EVERY_S` s, at one place (no ``position``: no cursor moves) and its last state kept; none
    under ``rhi -q``."""
    from tqdm import tqdm

    options["disable"] = options.get("disable", False) or quiet()
    if interactive():
        return tqdm(iterable, **options)
    options = {**options, "position": None, "leave": True, "dynamic_ncols": False,
               "mininterval": LINE_EVERY_S, "file": Lines(sys.stderr)}
    return tqdm(iterable, **options)
