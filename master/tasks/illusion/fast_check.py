"""Whether the fast (linearised) decoder may stand in for the exact one, checked per decoder.

The fast mode's error is not bounded by a formula: the decoders are ReLU networks, so g(mu) has kinks
and a pointwise bound on the linearisation error is far looser than what reaches the drift. So the
bound is checked where it matters, on the drift: each configured condition's first trial of the first
stimulation runs to the end twice in one lockstep batch, with the exact and with the fast decoder,
and the fast mode passes when every final drift is within ``DRIFT_BOUND`` of the largest exact one.

A verdict depends on the checkpoint's bytes and on every setting that moves a trial, so it is stored
under a hash of both: in the decoder cache, or shipped beside the package's default checkpoints
(``SHIPPED``), and any other decoder or configuration is checked once, when first run.

It is checked per protocol family, not per protocol: protocols that differ only in their stimulation schedule
(:data:`SCHEDULE_KEYS`: the stimulations, their delays, touch and blocks, the stroke's duration and stop, the
hidden conditions, the probes) share one verdict, checked on the family's representative, the protocol with the
shipped defaults' schedule (:func:`family`). The schedule moves when the ball strokes and what the hand feels,
not what the decoder is asked to decode: the rubber arm's offsets (``[conditions]``), the trial's length, the
decoder's, brain's and body's settings stay in the family. A model whose brain reads no pixel term runs no
decoder, so it is checked for nothing (:func:`verdicts`).
"""
from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path

import numpy as np

from rhi.master import config as configuration
from rhi.master import models
from rhi.master.cosim import ConfigError
from rhi.master.decoders.cache import SHIPPED, cache_folder, check_cache_folder, decoder_component
from rhi.master.tasks.illusion.measures import end_of_trial, measures
from rhi.master.runtime.pool import JOB_THREADS, Workers, run_jobs
from rhi.master.config.protocol import make_trial
from rhi.master.tasks.illusion.runner import bar_positions, step_bar
from rhi.master.tasks.illusion.wiring import run_batch
from rhi.master.outputs.files import atomic_write

log = logging.getLogger("rhi.fast_check")

DRIFT_BOUND = 0.01  # largest final-drift error of the fast mode, relative to the largest exact drift checked
# what does not move a checked trial (None: the whole table); the check runs the pymunk arm whatever experiment.body
NOT_TRIAL_SETTINGS = {"experiment": {"decoders", "trials", "batch_trials", "body"},
                      "decoder": {"conv_checkpoint", "vae_checkpoint", "fast"}, "train": None, "fmu": None}
# The stimulation schedule (docs/configuration.md, "Stimulation schedules"): a protocol family's members differ
# only here. A table name stands for the whole table.
SCHEDULE_KEYS = ("stimulations", "experiment.stimulations", "experiment.probe_times", "stimulus.stop_time",
                 "stimulus.stroke_duration", "rubber_arm.hidden_conditions")


def family(config: dict) -> dict:
    """The representative of ``config``'s protocol family: ``config`` with the shipped defaults' stimulation
    schedule (:data:`SCHEDULE_KEYS`), so the paper's protocol is its own representative."""
    shipped, represented = configuration.defaults(), {table: dict(values) for table, values in config.items()}
    for key in SCHEDULE_KEYS:
        table, _, name = key.partition(".")
        if name:
            represented[table][name] = shipped[table][name]
        else:
            represented[table] = shipped[table]
    return represented


def verdict_key(checkpoint: str, config: dict) -> str:
    """sha256 of the checkpoint's bytes and of the settings that move a trial (hex, 16 characters)."""
    settings = {table: {key: value for key, value in values.items() if key not in NOT_TRIAL_SETTINGS.get(table, ())}
                for table, values in config.items() if table not in NOT_TRIAL_SETTINGS or NOT_TRIAL_SETTINGS[table]}
    digest = hashlib.sha256(Path(checkpoint).read_bytes())
    digest.update(json.dumps(settings, sort_keys=True, default=str).encode())
    return digest.hexdigest()[:16]


def checked_trials(config: dict, kind: str) -> list:
    """The trials the check runs: each configured condition, trial 0 of the first stimulation."""
    stimulation = config["experiment"]["stimulations"][0]
    return [make_trial(config, kind, condition, stimulation, 0) for condition in config["experiment"]["conditions"]]


def check(config: dict, kind: str, checkpoint: str, progress: int | None = None) -> dict:
    """Run the checked trials with the exact and the fast decoder; the verdict (a job of :func:`verdicts`).
    progress: the terminal line of its progress bars (None: no bars).

    Returns
    -------
    dict
        ``fast`` (bool: the fast mode passed), ``relative_error`` (largest |fast - exact| final drift
        over the largest |exact| one), ``bound``, ``trials`` (condition names) and the final drifts, cm.
    """
    trials = checked_trials(config, kind)
    drifts = {}
    for mode in (False, True):
        with step_bar(f"{kind} fast check: {'fast' if mode else 'exact'} x{len(trials)}",
                      config["experiment"]["steps"], progress) as update:
            result = run_batch(decoder_component(kind, checkpoint, config, mode, JOB_THREADS), trials, config,
                               progress=update)
        drifts[mode] = end_of_trial(result.times, measures(result))["drift_cm"]
    scale = float(np.abs(drifts[False]).max())
    error = float(np.abs(drifts[True] - drifts[False]).max() / scale) if scale > 0 else float("inf")
    return {"fast": error <= DRIFT_BOUND, "reason": f"checked: drift error {error:.2%} of the largest drift "
                                                    f"({'within' if error <= DRIFT_BOUND else 'beyond'} {DRIFT_BOUND:.0%})",
            "relative_error": error, "bound": DRIFT_BOUND,
            "trials": [f"{t.condition} {t.stimulation} 0" for t in trials],
            "drift_exact_cm": drifts[False].tolist(), "drift_fast_cm": drifts[True].tolist()}


# A verdict as check() writes it: each field and its type(s).
VERDICT_FIELDS = {"fast": (bool,), "reason": (str,), "relative_error": (int, float), "bound": (int, float),
                  "trials": (list,), "drift_exact_cm": (list,), "drift_fast_cm": (list,)}


def verdict_problem(text: str) -> str | None:
    """What makes ``text`` not a verdict as :func:`check` writes it (None: it is one)."""
    try:
        verdict = json.loads(text)
    except (ValueError, RecursionError):
        return "not valid JSON"
    if not isinstance(verdict, dict):
        return "not a JSON object"
    for field, types in VERDICT_FIELDS.items():
        value = verdict.get(field)
        if not isinstance(value, types) or (bool not in types and isinstance(value, bool)):
            return f"{field} is {'missing' if field not in verdict else 'not a ' + types[0].__name__}"
    numbers = [verdict["relative_error"], verdict["bound"], *verdict["drift_exact_cm"], *verdict["drift_fast_cm"]]
    if not all(isinstance(n, (int, float)) and not isinstance(n, bool) for n in numbers) or \
            not all(isinstance(t, str) for t in verdict["trials"]):
        return "a list holds a value of the wrong type"
    if verdict["fast"] != (verdict["relative_error"] <= verdict["bound"]):
        return "fast disagrees with relative_error and bound"
    return None


def stored_verdict(cached: Path, shipped: Path) -> dict | None:
    """The stored verdict: the cache's, else the shipped one, else None (to be checked). A damaged one in
    the cache counts as missing, with a note on stderr (the check runs again and rewrites it); a damaged
    shipped one is a ConfigError (the installation is damaged). A damaged cached one beside a sound shipped
    one is replaced by the shipped one's copy."""
    damaged = False
    for path in (cached, shipped):
        if not path.is_file():
            continue
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as error:
            problem = f"unreadable ({getattr(error, 'strerror', None) or error})"
        else:
            problem = verdict_problem(text)
        if problem is None:
            if damaged:
                atomic_write(cached, text)
            return json.loads(text)
        if path == shipped:
            raise ConfigError(f"the shipped fast-check verdict {path} is damaged ({problem}); reinstall rhi")
        damaged = True
        log.warning(f"rhi: note: the fast-check verdict {path} is damaged ({problem}); "
                    f"{'using the shipped one' if shipped.is_file() else 'checking again'}")
    return None


def verdicts(config: dict, checkpoints: dict[str, str], workers: Workers | None = None,
             progress: bool = False) -> dict[str, dict]:
    """Per decoder: whether it runs fast, and why. ``[decoder] fast = false`` runs every decoder exact, and a
    model whose brain reads no pixel term runs none (nothing is checked for either); ``true`` runs each decoder
    fast if its check on the protocol's family (:func:`family`) passes (stored, or run now, the decoders side by
    side, on ``workers`` when given; with ``progress``, a line on stderr says so first)."""
    if not config["decoder"]["fast"]:
        return {kind: {"fast": False, "reason": "decoder.fast = false"} for kind in checkpoints}
    model = models.of(config)
    if not model.reads_pixels(config):
        return {kind: {"fast": False, "reason": f"no decoder runs: the {model.name} model reads no pixel term"}
                for kind in checkpoints}
    config = family(config)
    found, missing = {}, []
    for kind, checkpoint in checkpoints.items():
        name = f"fast-check-{kind}-{verdict_key(checkpoint, config)}.json"
        stored = stored_verdict(cache_folder() / name, SHIPPED / name)
        if stored is not None:
            found[kind] = stored
        else:
            missing.append((kind, cache_folder() / name))
    if missing:
        check_cache_folder()
        if progress:
            kinds = " and ".join(kind for kind, _ in missing)
            log.info(f"checking the fast mode of the {kinds} decoder{'s' * (len(missing) > 1)}: "
                     f"{len(checked_trials(config, missing[0][0]))} trials each, exact and fast "
                     "(once per decoder and settings)")
        jobs = [(config, kind, checkpoints[kind], position)
                for position, (kind, _) in zip(bar_positions(len(missing), progress, workers=workers), missing)]
        for (kind, path), verdict in zip(missing, run_jobs(check, jobs, workers=workers)):
            atomic_write(path, json.dumps(verdict, indent=2) + "\n")
            found[kind] = verdict
    return {kind: found[kind] for kind in checkpoints}
