"""Named protocols for the human phenomena the model is compared with (docs/design.md, Measures).

Each phenomenon is a sweep file shipped beside this module (a user copies and edits it) and a
report (:mod:`rhi.master.phenomena.report`) that reads the sweep's trial records and writes a table
and a figure with the human reference (``human.toml``, one source per number) beside the model:

- ``temporal-window``: drift, force and gamma against a fixed visuo-tactile delay, 0 to 1 s;
- ``distance``: drift and force against the rubber hand's lateral distance, 5 to 60 cm;
- ``time-course``: when the drift reaches half its final value under synchronous touch;
- ``persistence``: the stroking stops at 30 s; drift and gamma followed to 90 s;
- ``vision-only``: the drift under synchronous and asynchronous touch and under vision alone;
- ``blocks``: the drift after 120 s of stroking in blocks with pauses, against the blocks' length, under
  synchronous and asynchronous touch and vision alone.

Each protocol runs for both models (``--model``, docs/model.md) side by side: the causal model with
``causal.participants`` simulated participants per point, reported as the population's median and spread.

``rhi phenomenon NAME --out DIR`` runs the sweep (the ``rhi sweep`` machinery: resumable, a local
pool or Dask) and then the report. This module stays light (no matplotlib) so that the command
line can list the names.
"""
from __future__ import annotations

from importlib import resources
from pathlib import Path

FILES = {"temporal-window": "temporal_window.toml", "distance": "distance.toml", "time-course": "time_course.toml",
         "persistence": "persistence.toml", "vision-only": "vision_only.toml", "blocks": "blocks.toml"}
NAMES = tuple(FILES)


def sweep_file(name: str) -> Path:
    """The shipped sweep file of phenomenon ``name`` (``temporal-window`` -> ``temporal_window.toml``)."""
    return Path(str(resources.files("rhi.master.phenomena").joinpath(FILES[name])))


def human_file() -> Path:
    """The human reference data, one source per number."""
    return Path(str(resources.files("rhi.master.phenomena").joinpath("human.toml")))
