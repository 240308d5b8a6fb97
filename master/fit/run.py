"""`rhi fit`: the data and the fit file checked, the simulated participants run (resumably), the estimator
trained, every participant's posterior, the calibration on held-out simulations, the posterior predictive
check, and run.json.

DIR holds (docs/fit.md): fit.json (what the fit is: its fingerprint), simulations/ (a sweep folder: the prior's
simulated participants, a record per trial), estimator.pt, posterior.csv, estimates.csv, point.csv, calibration.csv,
recovery.csv, held_out.csv, predictive/ (a sweep folder) and predictive.csv, figures/, run.json. A killed fit
run again reruns only the missing trials and gives the same bytes (same seed, same CPU). The data may change
between runs of the same fit (same design): the simulations and the estimator are reused, the posteriors
computed anew (one trained estimator serves every participant of the design).
"""
from __future__ import annotations

import json
import logging
import shutil
import time
from pathlib import Path

import numpy as np

from rhi.master.cosim import ConfigError
from rhi.master.fit import point, report
from rhi.master.fit.calibration import calibrate
from rhi.master.fit.data import Data, read_data
from rhi.master.fit.plan import FitPlan, draw_participants, read_plan, simulation_seed
from rhi.master.runtime.context import RunContext
from rhi.master.fit.simulate import Pool, participants_sweep, simulate, simulated_statistics
from rhi.master.outputs.figures import save
from rhi.master.outputs.files import atomic_write
from rhi.master.outputs.own_paths import LockFile, make_folder
from rhi.master.outputs.provenance import package_versions, write_run_record
from rhi.master.sweeps.plan import canonical_hash

log = logging.getLogger("rhi.fit")

COMMAND = "rhi fit"
# settings that change only what is computed from the trained estimator: not part of the fit's identity
AFTER_TRAINING = ("workers", "posterior_samples", "calibration_samples", "predictive_draws", "predictive_participants")
# settings that were a fit's only behaviour before their key existed (a single estimator in the bounded space on
# z-scored statistics, random held-out draws): left out of the fingerprint, so that fits made then keep theirs
BEFORE_THEIR_KEYS = (("ensemble", 1), ("space", "bounded"), ("statistics", "z-score"), ("calibration_design", "random"))
OUTPUTS = ("fit.json", "simulations", "estimator.pt", "posterior.csv", "estimates.csv", "point.csv", "calibration.csv",
           "recovery.csv", "held_out.csv", "predictive", "predictive.csv", "figures", "run.json", ".lock",
           ".rhi-manifest.json")
# the reports a run writes over (its manifest lists each; a resumed fit refuses one edited since)
REPORTS = ("posterior.csv", "estimates.csv", "point.csv", "calibration.csv", "recovery.csv", "held_out.csv", "predictive.csv",
           "run.json", "figures/calibration.png", "figures/posterior_predictive.png")


def fingerprint(plan: FitPlan, sweep_fingerprint: str, data: Data | None = None) -> str:
    """What decides the simulations and the estimator: the design, the priors, the settings, the data's per-cell
    noise sds where it gives them (not the data's observed values, so that new participants of the same design
    reuse them)."""
    def named(table: dict) -> dict:
        return {k: v for k, v in table.items() if k not in AFTER_TRAINING and (k, v) not in BEFORE_THEIR_KEYS}

    identity = {"simulations": sweep_fingerprint, "parameters": [p.describe() for p in plan.parameters],
                "settings": named(plan.settings), "measures": plan.measures, "noise": plan.noise,
                "estimator": named(plan.estimator)}
    if plan.participant_noise:  # a fit without it keeps the fingerprint it had
        identity["participant_noise"] = plan.participant_noise
    if data is not None and cell_noise(data, plan):  # a fit without noise columns keeps the fingerprint it had
        identity["cell_noise"] = cell_noise(data, plan)
    return canonical_hash(identity)


def cell_noise(data: Data, plan: FitPlan) -> dict[str, float]:
    """The data's per-cell noise sds of the fitted measures, by statistic name (run.json's ``cell_noise``)."""
    sd, measures = data.noise_sd(plan.measures, {}), [m for _ in data.cells for m in plan.measures]
    return {name: float(value) for name, value, measure in zip(data_statistic_names(data, plan), sd, measures)
            if measure in data.noise}


def prepare_folder(out: Path, identity: str, simulations: str | None = None) -> None:
    """DIR new, empty, or an earlier run of this same fit; ConfigError otherwise (before anything is written).
    Its simulations/ and predictive/, when not empty, must be sweeps rhi wrote there, simulations/ the sweep of
    fingerprint ``simulations`` (this fit's): rhi fit has no --force, and never writes over another's."""
    from rhi.master.sweeps.folder import check_folder, only_leftovers, read_manifest

    check_folder(out)
    manifest = out / "fit.json"
    if out.is_dir() and any(out.iterdir()) and not only_leftovers(out, ("figures",)) and not (
            simulations is not None and only_simulations(out, simulations)):
        try:
            old = json.loads(manifest.read_text(encoding="utf-8")) if not manifest.is_symlink() else None
        except (OSError, ValueError, RecursionError):  # unreadable, not JSON, nested too deep: not a fit's
            old = None
        if not isinstance(old, dict) or old.get("command") != COMMAND:
            raise ConfigError(f"output folder {out} is not empty and holds no fit (no fit.json): choose another --out")
        if old.get("fingerprint") != identity:
            raise ConfigError(f"output folder {out} holds a different fit (its design, priors or settings differ): "
                              "choose another --out")
        for name in OUTPUTS:
            if (out / name).is_symlink():
                raise ConfigError(f"output {out / name} is a symbolic link; a fit writes only into folders of its own")
        for name in ("simulations", "predictive"):
            folder = out / name
            if not folder.is_dir() or not any(folder.iterdir()) or only_leftovers(folder):
                continue
            sweep = read_manifest(folder / "sweep.json")
            if sweep is None:
                raise ConfigError(f"output folder {folder} is not empty and holds no sweep rhi fit wrote (no "
                                  "sweep.json, or another's); a fit never writes over it: choose another --out")
            if name == "simulations" and simulations is not None and sweep["fingerprint"] != simulations:
                raise ConfigError(f"output folder {folder} holds another sweep than this fit's simulations (its "
                                  "sweep.json was changed); a fit never writes over it: choose another --out")
    try:
        out.mkdir(exist_ok=True)
        (out / "figures").mkdir(exist_ok=True)
    except OSError as error:
        raise ConfigError(f"cannot write {out}: {error.strerror or error}") from None
    atomic_write(manifest, json.dumps({"command": COMMAND, "fingerprint": identity}, indent=1) + "\n")


def only_simulations(out: Path, simulations: str) -> bool:
    """Whether ``out`` holds nothing but a ``simulations/`` sweep rhi wrote of fingerprint ``simulations``: another
    fit's simulated participants, copied to fit the same draws again with other statistics or estimator settings
    (docs/fit.md, "What DIR holds"); the fit starts there and runs only the trials missing."""
    from rhi.master.sweeps.folder import read_manifest

    folder = out / "simulations"
    names = {entry.name for entry in out.iterdir()} - {".lock"}  # the lock this fit holds
    if names != {"simulations"} or folder.is_symlink() or not folder.is_dir():
        return False
    sweep = read_manifest(folder / "sweep.json")
    return sweep is not None and sweep["fingerprint"] == simulations


def fit(data_path: str, config_path: str, out: Path, model: str | None = None, context: RunContext | None = None,
        log=print) -> dict:
    """The whole fit (module notes); returns run.json's content. context: its ``scheduler`` (None: a process pool
    of ``fit.workers``) and ``debug``."""
    context = context or RunContext()
    began = time.perf_counter()
    data = read_data(data_path)
    plan = read_plan(config_path, data, model)
    settings = plan.settings
    drawn = draw_participants(plan.parameters, settings)
    sweep = participants_sweep(plan, drawn, "prior")
    identity = fingerprint(plan, sweep.fingerprint, data)
    from rhi.master.sweeps.folder import check_folder

    check_folder(out)
    try:
        created = make_folder(out)  # DIR is this fit's to remove again only if this process made it
    except OSError as error:
        raise ConfigError(f"cannot write {out}: {error.strerror or error}") from None
    lock = LockFile(out / ".lock", f"another rhi fit is writing to {out}; wait for it to end or choose another --out")
    try:
        lock.acquire()
    except (ConfigError, OSError) as error:  # another fit's DIR now, even if this one made it: never removed
        if isinstance(error, OSError):
            raise ConfigError(f"cannot write {out}: {error.strerror or error}") from None
        raise
    try:
        prepare_folder(out, identity, sweep.fingerprint)
        own = reports_manifest(out)
        with Pool(context.scheduler, settings["workers"], context.debug) as pool:
            return _fit(data, plan, drawn, sweep, out, pool, log, began, identity, own)
    except ConfigError:  # refused before any simulation ran (a worker, a decoder): a DIR this fit made, and held
        # locked since, goes again
        if created and not any((out / "simulations" / "trials").glob("*.json")):
            lock.release()
            shutil.rmtree(out, ignore_errors=True)
        raise
    finally:
        lock.release()


def reports_manifest(out: Path):
    """DIR's manifest of the reports rhi fit wrote there (rhi.master.outputs.manifest), checked before anything runs:
    each report a run writes over must be the one rhi fit wrote, unchanged (an edited posterior.csv is refused,
    naming it); a fit folder of an older rhi, without one, has its reports listed as they are."""
    from rhi.master.outputs.manifest import NAME, Manifest

    own = Manifest.read(out, COMMAND)
    if own is None:
        own = Manifest(out, COMMAND)
        for name in REPORTS:
            own.add(name)
        return own
    blocking = [name for name in REPORTS
                if ((out / name).exists() or (out / name).is_symlink()) and not own.proven(name)]
    if blocking:
        raise ConfigError(f"output folder {out}: {', '.join(blocking)} would be written over but "
                          f"{'is' if len(blocking) == 1 else 'are'} not what rhi fit wrote there (not in its {NAME}, "
                          f"or changed since): move {'it' if len(blocking) == 1 else 'them'} or choose another --out")
    return own


def written(own, *names: str) -> None:
    """List the reports ``names`` as rhi fit has just written them, and save the manifest."""
    for name in names:
        own.add(name)
    own.save()


def _fit(data: Data, plan: FitPlan, drawn: np.ndarray, sweep, out: Path, pool, log, began, identity: str,
         own) -> dict:
    from rhi.master.fit import inference

    settings = plan.settings
    started = time.perf_counter()
    records, ran_now = simulate(sweep, out / "simulations", pool, "rhi fit: simulations")
    simulated_s = time.perf_counter() - started
    x = simulated_statistics(plan, sweep, records, data, "prior")
    valid = np.all(np.isfinite(x), axis=1)
    train_rows = np.flatnonzero(valid[:settings["simulations"]])
    held_rows = settings["simulations"] + np.flatnonzero(valid[settings["simulations"]:])
    if len(train_rows) < 10:
        raise ConfigError(f"only {len(train_rows)} of {settings['simulations']} simulated participants succeeded "
                          f"(see {out / 'simulations' / 'index.csv'}); narrow the priors")
    theta, x_train = drawn[train_rows], x[train_rows]
    estimators, training = load_or_train(plan, theta, x_train, out / "estimator.pt", identity)
    posterior = inference.posterior(plan.parameters, estimators, plan.estimator, x_train)

    timing = []
    samples = []
    for number, observed in enumerate(select(data, plan)):
        tick = time.perf_counter()
        samples.append(inference.sample(posterior, observed, settings["posterior_samples"],
                                        simulation_seed(settings["seed"], number, "posterior") % 2**62))
        timing.append(time.perf_counter() - tick)
    atomic_write(out / "point.csv", point.point_csv(plan.parameters, data.participants, posterior, select(data, plan),
                                                    np.stack(samples)))  # the adopted joint point (point.py)
    samples = report.natural(plan.parameters, np.stack(samples))
    atomic_write(out / "posterior.csv", report.posterior_csv(plan.parameters, data.participants, samples))
    atomic_write(out / "estimates.csv", report.estimates_csv(plan.parameters, data.participants, samples))
    written(own, "posterior.csv", "estimates.csv", "point.csv")

    calibration = None
    if len(held_rows):
        held = np.stack([inference.sample(posterior, x[row], settings["calibration_samples"],
                                          simulation_seed(settings["seed"], int(row), "calibration") % 2**62)
                         for row in held_rows])
        calibration = calibrate(held, drawn[held_rows])
        atomic_write(out / "calibration.csv", report.calibration_csv(plan.parameters, calibration))
        atomic_write(out / "recovery.csv", report.recovery_csv(
            plan.parameters, report.natural(plan.parameters, drawn[held_rows]), report.natural(plan.parameters, held),
            calibration["ranks"]))
        atomic_write(out / "held_out.csv", held_out_csv(data, plan, x[held_rows], held_rows, out))
        save(report.calibration_figure(plan.parameters, calibration, drawn[held_rows]),
             out / "figures" / "calibration.png", dpi=report.FIGURE_DPI)
        written(own, "calibration.csv", "recovery.csv", "held_out.csv", "figures/calibration.png")

    predictive = predictive_check(data, plan, posterior, out, pool, own)
    result = run_record(data, plan, sweep, records, training, timing, calibration, predictive, valid, held_rows,
                        simulated_s, ran_now, time.perf_counter() - began)
    write_run_record(out, result)
    written(own, "run.json")
    return result


def load_or_train(plan: FitPlan, theta, x, path: Path, identity: str):
    """The estimators (``fit.estimator.ensemble`` of them) saved in ``path`` when they were trained on this very
    training set with these settings, else trained now and saved (weights only: torch.load(weights_only=True)
    reads them back). Member k is trained from the seed ``simulation_seed(seed, k, "estimator")``."""
    import torch

    from rhi.master.fit import inference

    trained_on = canonical_hash({"fit": identity, "theta": theta.tolist(), "x": x.tolist()})
    seeds = [simulation_seed(plan.settings["seed"], k, "estimator") % 2**62 for k in range(plan.estimator["ensemble"])]
    if path.is_file() and not path.is_symlink():
        try:
            saved = torch.load(path, weights_only=True)
        except Exception:  # noqa: BLE001: a damaged or foreign file is trained over
            saved = None
        if isinstance(saved, dict) and saved.get("trained_on") == trained_on and len(saved.get("states", ())) == len(seeds):
            try:  # its weights must fit the estimator these settings build, and be finite (NaN never samples)
                estimators = [inference.rebuild(plan.parameters, theta, x, plan.estimator, state, seed)
                              for state, seed in zip(saved["states"], seeds)]
                problem = next(filter(None, map(inference.unusable, estimators)), None)
                summary = json.loads(saved["summary"])
            except (RuntimeError, KeyError, TypeError, ValueError, AttributeError, RecursionError) as error:
                lines = [line.strip() for line in str(error).strip().splitlines() if line.strip()]
                problem = f"its weights do not fit this fit's estimator ({(lines[1:2] or lines[:1] or ['?'])[0]})"
            if problem is None and isinstance(summary, dict):
                return estimators, summary
            problem = problem or "its summary is not a JSON object"
            log.warning(f"rhi fit: note: {path} does not hold a usable estimator ({problem}); training it again")
    trained = [inference.train(plan.parameters, theta, x, plan.estimator, seed) for seed in seeds]
    estimators = [estimator.eval() for estimator, _ in trained]
    summary = {**trained[0][1], "seconds": round(sum(part["seconds"] for _, part in trained), 3)}
    if len(trained) > 1:
        summary["members"] = [part["epochs"] for _, part in trained]
    state = {"states": [estimator.state_dict() for estimator in estimators], "trained_on": trained_on,
             "summary": json.dumps(summary)}
    atomic_write(path, lambda file: torch.save(state, file))
    return estimators, summary


def held_out_csv(data: Data, plan: FitPlan, x: np.ndarray, rows, out: Path) -> str:
    """The held-out simulated participants as a data file in ``out`` (their statistics, noise included; its
    protocols' paths relative to ``out``): a fit of it is a recovery of the parameters recovery.csv lists
    (participant simN: prior draw N)."""
    import os

    from rhi.master.outputs.tables import csv_text, number

    parts = data.designs()
    condition = "offset_m" if any(p.conditions for p in parts) else "condition"
    stimulation = "delay_s" if any(p.stimulations for p in parts) else "stimulation"
    noisy = [m for m in plan.measures if m in data.noise]  # its noise columns too: a refit adds the same noise
    header = ["participant", *(["protocol"] if data.parts else []), condition, stimulation,
              *(["baseline"] if any(p.contrasts for p in parts) else []),
              *(["time_s"] if any(p.time_s is not None for p in parts) else []), *plan.measures,
              *(f"{m}_sem" for m in noisy)]
    cells = [(part, c, s) for part in parts for c, s in part.cells]
    lines = []
    for values, row in zip(x.reshape(len(x), len(data.cells), len(plan.measures)), rows):
        for n, ((part, c, s), cell) in enumerate(zip(cells, values)):
            named, baseline = part.contrasts.get(s, (s, ""))
            lines.append([f"sim{int(row)}", *([os.path.relpath(part.protocol_path(), out)] if data.parts else []),
                          number(part.conditions[c]) if part.conditions else c,
                          number(part.stimulations[s]) if part.stimulations else named,
                          *([baseline] if "baseline" in header else []),
                          *([number(part.time_s)] if "time_s" in header else []), *(number(v) for v in cell),
                          *(number(data.noise[m][n]) for m in noisy)])
    return csv_text(header, lines)


def predictive_check(data: Data, plan: FitPlan, posterior, out: Path, pool, own) -> dict | None:
    """Simulate ``fit.predictive_draws`` posterior draws of each of the first ``fit.predictive_participants``
    participants (a sweep in DIR/predictive); predictive.csv and figures/posterior_predictive.png."""
    from rhi.master.fit import inference

    settings = plan.settings
    count = min(settings["predictive_participants"], len(data.participants))
    draws = settings["predictive_draws"]
    if not count or not draws:
        return None
    observed = select(data, plan)[:count]
    values = np.concatenate([inference.sample(posterior, observed[n], draws,
                                              simulation_seed(settings["seed"], n, "predictive") % 2**62)
                             for n in range(count)])
    sweep = participants_sweep(plan, values, "predictive")
    records, _ = simulate(sweep, out / "predictive", pool, "rhi fit: posterior predictive", replace=True)
    predicted = simulated_statistics(plan, sweep, records, data, "predictive").reshape(count, draws, -1)
    names = data_statistic_names(data, plan)
    atomic_write(out / "predictive.csv", report.predictive_csv(names, data.participants[:count], observed, predicted))
    save(report.predictive_figure(names, data.participants[:count], observed, predicted),
         out / "figures" / "posterior_predictive.png", dpi=report.FIGURE_DPI)
    written(own, "predictive.csv", "figures/posterior_predictive.png")
    return {"participants": count, "draws": draws, "trials": len(sweep.trials)}


def data_statistic_names(data: Data, plan: FitPlan) -> list[str]:
    """The fitted statistics' names, ``measure[condition/stimulation]``, cell by cell."""
    return [f"{m}[{c}/{s}]" for c, s in data.cells for m in plan.measures]


def select(data: Data, plan: FitPlan) -> np.ndarray:
    """The data's statistics of the fitted measures only (fit.measures may leave some out)."""
    positions = [data.measures.index(m) for m in plan.measures]
    shaped = data.observed.reshape(len(data.participants), len(data.cells), len(data.measures))
    return shaped[:, :, positions].reshape(len(data.participants), -1)


def run_record(data, plan, sweep, records, training, timing, calibration, predictive, valid, held_rows,
               simulated_s, ran_now, wall_s) -> dict:
    """run.json's content: the data, the plan, the simulations and their timing, the estimator and its training,
    the versions, and the calibration and the posterior predictive check when they ran."""
    import torch

    from rhi.master.fit.calibration import LEVELS

    steps = [config["experiment"]["steps"] for config in plan.configs()]
    result = {
        "command": COMMAND, "data": data.path, "participants": data.participants, "design_cells": data.cells,
        "statistics": data_statistic_names(data, plan), "model": plan.settings["model"],
        "parameters": [p.describe() for p in plan.parameters], "settings": plan.settings, "measures": plan.measures,
        "noise": plan.noise, **({"cell_noise": cell_noise(data, plan)} if cell_noise(data, plan) else {}),
        **({"participant_noise": plan.participant_noise} if plan.participant_noise else {}),
        "estimator": {**plan.estimator, "torch_threads": torch.get_num_threads(), **training},
        "seeds": {"fit": plan.settings["seed"], "simulated_participants": [p["experiment.seed"] for p in sweep.points]},
        "simulations": {"participants": len(sweep.points), "trials": len(sweep.trials),
                        "failed_participants": int((~valid).sum()), "trials_run_now": ran_now,
                        "wall_s_now": round(simulated_s, 3),
                        "trials_per_s_now": round(ran_now / simulated_s, 3) if ran_now and simulated_s else None,
                        "cpu_s_per_trial": cpu_per_trial(records),
                        "steps_per_trial": steps if len(steps) > 1 else steps[0],  # per protocol, if several
                        "resolution": plan.base["experiment"]["resolution"]},
        "posterior_seconds_per_participant": {"max": round(max(timing), 4), "mean": round(float(np.mean(timing)), 4)},
        "wall_s": round(wall_s, 3), "configuration": plan.base, "versions": package_versions(),
    }
    if data.parts:  # each protocol's keys over the configuration
        result["protocols"] = {part.protocol: keys for part, keys in zip(data.parts, plan.designs)}
    for package in ("sbi", "nflows", "zuko"):
        try:
            from importlib import metadata
            result["versions"][package] = metadata.version(package)
        except Exception:  # noqa: BLE001
            pass
    if calibration is not None:
        result["calibration"] = {
            "held_out": calibration["participants"], "samples_per_participant": calibration["samples"],
            "sbc_test": "scipy.stats.chisquare of the binned ranks; scipy.stats.kstest of (rank + 1/2) / (L + 1)",
            "sbc_verdict": calibration["verdict"],
            **{p.key: {"correlation": float(calibration["recovery"]["correlation"][d]),
                       "sd_ratio": float(calibration["recovery"]["sd_ratio"][d]),
                       **{f"coverage_{int(level * 100)}": float(calibration["coverage"][level][d]) for level in LEVELS},
                       "sbc_chisquare_p": float(calibration["uniformity"]["chisquare_p"][d]),
                       "sbc_ks_p": float(calibration["uniformity"]["ks_p"][d])}
               for d, p in enumerate(plan.parameters)}}
    if predictive is not None:
        result["predictive"] = predictive
    del records
    return result


def cpu_per_trial(records: dict[str, dict]) -> float | None:
    """The workers' CPU seconds per trial over the records that say (each a chunk's CPU time over its size):
    the simulator's cost apart from what else the machine runs."""
    values = [r["cpu_s"] / r["batch"] for r in records.values() if r.get("status") == "ok" and "cpu_s" in r]
    return round(float(np.mean(values)), 6) if values else None
