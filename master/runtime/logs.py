"""The command line's log: rhi's messages (the ``rhi`` logger and its children) and Python's warnings (sbi's,
torch's, distributed's) on standard error, one line each, at the level ``-q``/``-v`` set.

Outside the command line rhi configures no logging: a script or a notebook sees rhi's warnings through Python's
last-resort handler, and its progress notes only once it configures the ``rhi`` logger itself.
"""
from __future__ import annotations

import logging
import sys
from contextlib import contextmanager

LOGGER = "rhi"
WARNINGS = "py.warnings"  # the logger logging.captureWarnings sends Python's warnings to
LEVELS = {-1: logging.ERROR, 0: logging.INFO, 1: logging.DEBUG}  # -q, neither, -v


def level_of(verbosity: int) -> int:
    """The log level of ``verbosity`` (-1: ``-q``, errors only; 0: notes and progress; 1: ``-v``, the run's steps)."""
    return LEVELS[max(-1, min(1, verbosity))]


class StandardError(logging.Handler):
    """Each record as one line on standard error, looked up when written (a redirected stderr is followed)."""

    def emit(self, record: logging.LogRecord) -> None:
        """Write ``record``, formatted, as a line of the current ``sys.stderr``."""
        try:
            sys.stderr.write(self.format(record) + "\n")
            sys.stderr.flush()
        except (OSError, ValueError):  # a closed or full stderr: nothing left to tell it on
            pass


class OneLine(logging.Formatter):
    """rhi's messages as they are (each names its command); anything else prefixed with its origin, and one line:
    a warning ``FILE:LINE: Category: text`` without the source line Python adds below it."""

    def format(self, record: logging.LogRecord) -> str:
        """``record`` as its one line (class notes)."""
        message = record.getMessage()
        if record.name == LOGGER or record.name.startswith(LOGGER + "."):
            prefix = "debug: " if record.levelno <= logging.DEBUG else ""
            return prefix + message
        if record.name == WARNINGS:  # FILE:LINE: Category: text, then the source line
            return "rhi: warning: " + " ".join((message.strip().splitlines() or [""])[0].split())
        return f"rhi: {record.name}: {' '.join(message.split())}"


@contextmanager
def configured(verbosity: int):
    """rhi's log and Python's warnings on standard error at ``verbosity``'s level for the block, as they were after.

    Python's warnings go through logging (``logging.captureWarnings``) under the filters in force (Python's
    default: once per place each arises), hidden by ``-q``."""
    level = level_of(verbosity)
    handler = StandardError(level)
    handler.setFormatter(OneLine())
    loggers = [logging.getLogger(LOGGER), logging.getLogger(WARNINGS)]
    before = [(logger.level, logger.propagate) for logger in loggers]
    for logger in loggers:
        logger.addHandler(handler)
        logger.setLevel(level)
        logger.propagate = False  # not twice, where the root logger has a handler of its own
    logging.captureWarnings(True)
    try:
        yield level
    finally:
        logging.captureWarnings(False)
        for logger, (old_level, propagate) in zip(loggers, before):
            logger.removeHandler(handler)
            logger.setLevel(old_level)
            logger.propagate = propagate
