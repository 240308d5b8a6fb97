"""The one-call API behind :mod:`rhi`: an experiment in memory, its results as data frames and arrays, the
configuration, the model registry and sweeps. Each call runs from a notebook, an IPython shell, a script with or
without an ``if __name__ == "__main__":`` guard, and a Dask worker (:func:`rhi.master.runtime.pool.may_spawn`)."""
from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

# The per-trial columns of trials.csv that name a trial, and their dtypes in :attr:`Experiment.trials`.
TRIAL_IDENTITY = {"decoder": "category", "condition": "category", "stimulation": "category", "trial": "int64",
                  "seed": "int64"}


def load_config(path: str | Path | None = None, *, quick: bool = False, preset: str | None = None,
                model: str = "paper", **overrides) -> dict:
    """A configuration: the defaults, then ``[quick]``, the preset, the model, the file and ``overrides``.

    Parameters
    ----------
    path : str or Path, optional
        A TOML file of keys to change (docs/configuration.md).
    quick : bool
        The small fast settings (32x32 images, short trials).
    preset : str, optional
        A shipped preset, e.g. ``"paper"`` (the paper's scale, 256x256).
    model : str
        A registered model's name or ``FILE.py:Class`` (default: the paper's).
    **overrides
        ``table__key=value`` pairs, e.g. ``experiment__trials=1`` (a double underscore for the dot).

    Returns
    -------
    dict
        The validated configuration.

    Examples
    --------
    >>> cfg = load_config(quick=True, experiment__steps=20)
    >>> cfg["experiment"]["steps"]
    20
    """
    from rhi.master import config

    loaded = config.load(path, {key.replace("__", "."): value for key, value in overrides.items()}, quick=quick,
                         preset_name=preset, model_name=model)
    config.validate(loaded)
    return loaded


def models() -> tuple[str, ...]:
    """The registered models' names: the built-in ones, then those of installed packages (``rhi.models``).

    Examples
    --------
    >>> "ownership" in models()
    True
    """
    from rhi.master import models as registry

    return registry.names()


def run(task, config: dict | None = None, *, model: str = "paper", quick: bool = False, **overrides):
    """Run a task in memory: a registered one (:data:`rhi.tasks`) or one of one's own (``"FILE.py:Class"``).

    Parameters
    ----------
    task : str or rhi.master.tasks.Task
        ``"illusion"``, ``"reach"``, ``"moving-hand"``, ``"reach-after"``, an entry point's name, or
        ``"path/to/file.py:Class"`` (``examples/my_task.py``).
    config : dict, optional
        A configuration of the task (default: the task's own, ``task.load``, with ``model`` and ``quick``).
    model : str
        A registered model's name or ``FILE.py:Class`` (when ``config`` is not given).
    quick : bool
        The small fast settings, where the task has them (when ``config`` is not given).
    **overrides
        ``table__key=value`` pairs over the configuration, e.g. ``experiment__steps=12``.

    Returns
    -------
    rhi.master.tasks.TaskResult
        ``.trials``, ``.times`` (s), ``.per_step`` (each measure per step and trial), ``.tables()`` (``{file name:
        text or DataFrame}``, what the command line writes), ``.provenance``, ``.write(DIR)``.

    Examples
    --------
    >>> result = run("moving-hand", experiment__steps=12, experiment__decoders=["conv"],
    ...              moving_hand__delays=[0.0, 0.1], moving_hand__period=0.2)
    >>> list(result.tables())
    ['moving_hand.csv']
    >>> result.tables()["moving_hand.csv"].splitlines()[0]
    'decoder,delay_s,drift_cm,drift_relative,gamma,gamma_relative'
    """
    from rhi.master import config as configuration
    from rhi.master import tasks as registry

    chosen = registry.get(task) if isinstance(task, str) else task
    dotted = {key.replace("__", "."): value for key, value in overrides.items()}
    if config is None:
        config = chosen.load(None, dotted, quick, model)
    elif dotted:
        config = configuration.merge(config, configuration.nest(dotted))
        configuration.validate(config)
    return registry.run(chosen, config)


@dataclass
class Experiment:
    """An experiment's run, in memory, as data.

    Attributes
    ----------
    result : rhi.master.tasks.illusion.publish.ExperimentResult
        The run as the command line writes it (``result.summary``: summary.csv's rows).
    """

    result: object

    @property
    def config(self) -> dict:
        """The configuration it ran."""
        return self.result.config

    @property
    def failures(self) -> dict:
        """Each failed trial and its error (the other trials ran to the end)."""
        return self.result.failures

    @property
    def provenance(self) -> dict:
        """What run.json records: model, body, checkpoints, fast-mode verdicts, seeds, versions, timings."""
        return self.result.provenance

    @property
    def summary(self):
        """summary.csv as a pandas DataFrame: one row per decoder x condition x stimulation, the values of the
        file (``%.6g``), the units in the column names."""
        import pandas as pd

        from rhi.master.outputs import tables

        columns = tables.summary_columns(self.config["experiment"]["probe_times"])
        frame = pd.read_csv(io.StringIO(tables.csv_text(columns, self.result.summary)))
        return frame.astype({key: "category" for key in ("decoder", "condition", "stimulation") if key in frame})

    @property
    def trials(self):
        """trials.csv as a pandas DataFrame: one row per trial x step, the values of the file (``%.6g``)."""
        import pandas as pd

        from rhi.master.outputs import tables

        text = tables.trials_csv(self.result.trials, self.result.times, self.result.per_step)
        frame = pd.read_csv(io.StringIO(text))
        return frame.astype({key: kind for key, kind in TRIAL_IDENTITY.items() if key in frame})

    @property
    def per_step(self):
        """Every measure per trial and step, unrounded, as an xarray Dataset: per_step.nc's contents.

        Dimensions ``trial`` and ``time_s``; coordinates ``decoder``, ``condition``, ``stimulation``,
        ``index`` and ``seed`` along ``trial``; attributes ``model`` and ``seed``
        (:func:`rhi.master.tasks.illusion.publish.per_step_dataset`)."""
        from rhi.master.tasks.illusion.publish import per_step_dataset

        return per_step_dataset(self.result)

    def write(self, out: str | Path, force: bool = False) -> None:
        """Write the folder ``rhi experiment --out DIR`` writes (summary.csv, trials.csv, per_step.nc, figures/,
        run.json), whole or not at all."""
        self.result.write(out, force)


def run_experiment(config: dict | None = None, *, model: str | None = None, quick: bool | None = None,
                   trials: int | None = None, steps: int | None = None, seed: int | None = None,
                   body: str | None = None, processes: int | None = None, progress: bool = False) -> Experiment:
    """The paper's protocol (or part of it) in memory.

    Parameters
    ----------
    config : dict, optional
        A configuration (:func:`load_config`); default: the shipped one, changed by the keywords below.
    model : str, optional
        A registered model (default: the configuration's, else the paper's).
    quick : bool, optional
        The small fast settings; default: on when ``trials`` or ``steps`` is given without a ``config``.
    trials, steps, seed : int, optional
        ``experiment.trials`` (per cell), ``experiment.steps`` (of 20 ms), ``experiment.seed``.
    body : str, optional
        A body FMU to swap in (default: the pymunk arm).
    processes : int, optional
        Most worker processes (default: the usable cores; in a script that cannot spawn them, 1).
    progress : bool
        Progress bars on standard error.

    Returns
    -------
    Experiment
        ``.summary`` (DataFrame, one row per cell), ``.trials`` (DataFrame, one row per trial x step),
        ``.per_step`` (xarray Dataset, trial x time), ``.write(DIR)``.

    Examples
    --------
    >>> import rhi
    >>> r = rhi.run_experiment(trials=1, steps=10)   # doctest: +SKIP
    >>> r.summary.shape                              # doctest: +SKIP
    (12, 24)
    """
    from rhi.master.runtime.context import RunContext
    from rhi.master.tasks.illusion.publish import run_experiment as run_protocol

    changes = {"experiment__trials": trials, "experiment__steps": steps, "experiment__seed": seed}
    changes = {key: value for key, value in changes.items() if value is not None}
    if config is None:
        config = load_config(quick=bool(changes) if quick is None else quick, model=model or "paper", **changes)
    elif changes or model or quick:
        raise ValueError("give either config or the keywords model, quick, trials, steps, seed (load_config "
                         "takes the same keywords)")
    return Experiment(run_protocol(config, body, RunContext(progress=progress, processes=processes)))


def load_sweep(path: str | Path, model: str | None = None):
    """A sweep file (docs/sweeps.md) as its plan: points, configurations, trials (``rhi.master.sweeps.plan.Sweep``)."""
    from rhi.master.sweeps import plan

    return plan.load(path, model)


def run_sweep(sweep):
    """Every trial of a sweep (:func:`load_sweep`) run here, nothing written, as a pandas DataFrame: a row per
    trial, its point's values (one column per swept key), ``id``, ``point``, ``status`` and its end-of-trial
    outcome (``drift_cm``, ``force_n``, ``gamma_final``, ...), or ``error`` for a failed trial."""
    import pandas as pd

    from rhi.master.sweeps.runner import run_in_memory

    rows = []
    for record in run_in_memory(sweep).values():
        outcome = record.get("outcome") or {}
        rows.append({**sweep.points[record["point"]], "id": record["id"], "point": record["point"],
                     "status": record.get("status"), **outcome,
                     **({"error": record["error"]} if "error" in record else {})})
    return pd.DataFrame(rows)


def power(config: dict, ns, studies: int, contrast: tuple[str, str] = ("sync", "async"), measure: str = "drift_cm",
          alpha: float = 0.05):
    """The power of a paired t test of ``contrast`` on ``measure``, over study sizes, by simulated studies of the
    configuration's ``[population]`` (docs/population.md; ``rhi power``).

    Parameters
    ----------
    config : dict
        A configuration with a ``[population]`` (:func:`load_config`).
    ns : sequence of int
        Participants per study.
    studies : int
        Simulated studies per size, K.
    contrast : (str, str)
        The two stimulations compared within each participant.
    measure : str
        The end-of-trial measure (a trials.csv column).
    alpha : float
        The test's level.

    Returns
    -------
    pandas.DataFrame
        A row per size: ``n_participants``, ``studies``, ``power``, ``power_mc_error`` (sqrt(p (1 - p) / K)), and
        the mean and the between-participant sd of the difference in the measure's unit.
    """
    import pandas as pd

    from rhi.master.studies import power as studies_power

    curve = studies_power.power(studies_power.protocol_simulator(config, tuple(contrast), measure), ns=tuple(ns),
                                studies=studies, alpha=alpha)
    return pd.DataFrame([{"n_participants": p.n, "studies": p.studies, "power": p.power, "power_mc_error": p.mc_error,
                          f"mean_difference_{measure}": p.mean_difference,
                          f"sd_difference_{measure}": p.sd_difference} for p in curve])
