"""rhi: a deep active inference model of the rubber-hand illusion (Rood, van Gerven & Lanillos 2020) as a
co-simulation of FMU-style components.

The public API, one call per job. Importing ``rhi`` is light: each name loads its module when first used.

========================  ======================================================================================
``run_experiment``        the paper's protocol (or a small part of it) in memory: an :class:`Experiment`
``Experiment``            its result: ``summary`` and ``trials`` as pandas DataFrames, ``per_step`` as an xarray
                          Dataset, ``write(DIR)`` for the files ``rhi experiment`` writes
``load_config``           a configuration: the defaults, a preset, a model, a file, overrides
``models``                the registered models' names (built in, entry points ``rhi.models``)
``tasks``                 the registered tasks by name (built in, entry points ``rhi.tasks``): ``rhi.tasks["reach"]``
``run``                   any task (a registered one or ``FILE.py:Class``) in memory: a result with ``tables()``
``load_sweep``            a sweep file as a plan of trials; ``run_sweep`` runs it in memory
``power``                 the power of a paired contrast over study sizes, by simulated studies of a population
``fit``                   ``rhi fit`` in memory over arrays: ``read_data``, ``read_plan``, ``draw``, ``simulate``,
                          ``train``, ``sample`` (:mod:`rhi.master.fit.memory`)
========================  ======================================================================================

Examples
--------
>>> import rhi
>>> rhi.models()[:3]
('paper', 'causal', 'ownership')
>>> rhi.load_config(quick=True)["experiment"]["resolution"]
32
>>> list(rhi.tasks)
['illusion', 'reach', 'moving-hand', 'reach-after']
"""
from __future__ import annotations

import importlib
from importlib import metadata
from pathlib import Path

# Installed, rhi.components and rhi.master are the folders components/ and master/ (setup.py maps them). Run from a
# source tree that is not installed (a checkout on PYTHONPATH), they are found beside this folder.
_TREE = Path(__file__).resolve().parent.parent
if (_TREE / "master" / "__init__.py").is_file() and (_TREE / "components" / "__init__.py").is_file():
    __path__.append(str(_TREE))

try:
    __version__ = metadata.version("rhi")
except metadata.PackageNotFoundError:  # a source tree that is not installed
    __version__ = "0+unknown"

# name -> "module:attribute" (attribute "" for the module itself), imported on first use
_EXPORTS = {
    "run_experiment": "rhi.api:run_experiment",
    "Experiment": "rhi.api:Experiment",
    "load_config": "rhi.api:load_config",
    "models": "rhi.api:models",
    "tasks": "rhi.master.tasks:TASKS",
    "run": "rhi.api:run",
    "load_sweep": "rhi.api:load_sweep",
    "run_sweep": "rhi.api:run_sweep",
    "fit": "rhi.fit:",
    "power": "rhi.api:power",
}
__all__ = sorted(_EXPORTS) + ["__version__"]


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'rhi' has no attribute {name!r}")
    module, _, attribute = _EXPORTS[name].partition(":")
    value = importlib.import_module(module)
    value = getattr(value, attribute) if attribute else value
    globals()[name] = value
    return value


def __dir__():
    return __all__
