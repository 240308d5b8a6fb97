"""The whole protocol in fast mode, as `rhi experiment` runs it (in a child process, for its peak memory), its
projection when no trained decoders are cached, and the fast mode's drift error against the exact integrator."""
from __future__ import annotations

import json
import os
import resource
import sys
import time
from dataclasses import asdict

import numpy as np
import torch

from rhi.components.body import kinematics
from rhi.components.vision.component import Decoder, available_cores
from rhi.components.vision.fast import LinearisedDecoder
from rhi.components.vision.optimised import optimised
from rhi.master.tasks import illusion as experiment
from rhi.master.bench.settings import BenchSettings, protocol_config, protocol_trials, timed, untrained
from rhi.master import config as configuration


def trained_protocol(settings: BenchSettings) -> tuple[dict, dict] | None:
    """The configuration of ``protocol_trained`` (its protocol, ``protocol_steps`` steps) and the cached trained
    decoders it names, if every one of them is in the cache; else None."""
    if not settings.protocol_trained:
        return None
    from rhi.master.decoders.cache import checkpoint_path
    quick = settings.protocol_trained == "quick"
    config = configuration.load(quick=quick, preset_name=None if quick else settings.protocol_trained,
                                overrides={"experiment.steps": settings.protocol_steps})
    paths = {kind: checkpoint_path(kind, config) for kind in config["experiment"]["decoders"]}
    return (config, paths) if all(os.path.isfile(path) for path in paths.values()) else None


def trained_run(config: dict, paths: dict, threads: int) -> dict:
    """The protocol as `rhi experiment` runs it once its decoders are cached: each decoder's trials in one lockstep
    batch through the decoder component the configuration makes (the paper preset: the fast mode); the time
    includes loading each decoder."""
    from rhi.master.decoders.cache import decoder_component
    torch.set_num_threads(threads)
    began, stepping, trials, parts = time.perf_counter(), 0.0, 0, {}
    relinearisations, points, calls = [], 0, 0
    for kind, path in paths.items():
        batch = [t for t in experiment.plan(config) if t.decoder == kind]
        decoder = decoder_component(kind, path, config)
        result = experiment.run_batch(decoder, batch, config)
        stepping += result.timings["total_s"] - result.timings["setup_s"]
        for key, value in result.timings.items():
            if key.startswith("step_s."):
                parts[key[7:]] = parts.get(key[7:], 0.0) + value
        trials += len(batch)
        relinearisations += list(getattr(decoder, "relinearisations", []))
        points += getattr(decoder, "decoder_points", 0)
        calls += getattr(decoder, "decoder_calls", 0)
    seconds, steps = time.perf_counter() - began, config["experiment"]["steps"]
    return {"preset": config["train"]["preset"], "resolution": config["experiment"]["resolution"],
            "weights": "trained: " + ", ".join(f"{kind} {os.path.basename(path)}" for kind, path in paths.items()),
            "trained": True, "checkpoints": paths, "fast_mode": config["decoder"]["fast"], "trials": trials,
            "steps": steps, "seconds": seconds, "agent_steps_per_s": trials * steps / seconds,
            "stepping_agent_steps_per_s": trials * steps / stepping,
            "share": {key: value / stepping for key, value in parts.items()},
            "relinearisations_per_trial": float(np.mean(relinearisations)) if relinearisations else 0.0,
            "decoder_points_per_trial": points / trials, "decoder_calls": calls, "peak_rss_mb": peak_rss_mb()}


def protocol_run(settings: BenchSettings) -> dict:
    """The whole protocol in fast mode (run in a child: its peak RSS is the run's): with the trained decoders of
    ``protocol_trained`` when they are cached, else with an untrained one at ``protocol_preset`` (whose rate
    :func:`projected` corrects with the decoder calls of a trained decoder, replayed)."""
    threads = settings.threads or available_cores()
    trained = trained_protocol(settings)
    if trained is not None:
        return trained_run(*trained, threads)
    torch.set_num_threads(threads)
    preset, resolution = settings.protocol_preset
    model = optimised(untrained(preset, resolution, settings.seed))
    config = protocol_config(resolution, settings.protocol_steps)
    trials = protocol_trials(config, settings.batch)
    with torch.no_grad():  # warm-up: first-use imports and kernels
        model.predict_with_jacobian(beliefs(1))
    decoder = LinearisedDecoder(model, relinearise_tolerance=settings.tolerance, threads=threads, fast_layout=False)
    result, seconds = timed(lambda: experiment.run_batch(decoder, trials, config))
    stepping = result.timings["total_s"] - result.timings["setup_s"]
    rss = peak_rss_mb()
    return {"preset": preset, "resolution": resolution, "weights": f"untrained, torch seed {settings.seed}",
            "trained": False, "trials": len(trials), "steps": settings.protocol_steps, "seconds": seconds,
            "agent_steps_per_s": len(trials) * settings.protocol_steps / seconds,
            "stepping_agent_steps_per_s": len(trials) * settings.protocol_steps / stepping,
            "share": {k[7:]: v / stepping for k, v in result.timings.items() if k.startswith("step_s.")},
            "relinearisations_per_trial": float(decoder.relinearisations.mean()),
            "decoder_points_per_trial": decoder.decoder_points / len(trials), "decoder_calls": decoder.decoder_calls,
            "peak_rss_mb": rss}


def beliefs(count: int) -> torch.Tensor:
    """``count`` distinct beliefs near the rest pose (count, 2) deg."""
    offsets = torch.linspace(-1, 1, 2 * count, dtype=torch.float32).view(count, 2)
    return torch.tensor(kinematics.REST_POSE, dtype=torch.float32) + offsets


def replayed_calls(call_sizes: list[int], settings: BenchSettings) -> float:
    """Seconds the protocol preset's decoder takes for decoder calls of these sizes (each size: best of 3)."""
    model = optimised(untrained(*settings.protocol_preset, settings.seed))
    sizes, counts = np.unique(np.asarray(call_sizes, dtype=int), return_counts=True)
    total = 0.0
    with torch.no_grad():
        model.predict_with_jacobian(beliefs(1))  # warm-up
        for size, count in zip(sizes, counts):
            points = beliefs(int(size))
            seconds = min(timed(lambda: model.predict_with_jacobian(points))[1] for _ in range(3))
            total += int(count) * seconds
    return total


def projected(protocol: dict, error: dict, settings: BenchSettings) -> float | None:
    """The protocol's rate had its untrained decoder made the decoder calls the trained default decoder made in the
    drift-error run (how often and how many points depends on how mu moves, in degrees, not on pixels): those
    calls replayed on the protocol's decoder, scaled from that run's trials to the protocol's."""
    if "call_sizes" not in error:
        return None
    extra = replayed_calls(error["call_sizes"], settings) * protocol["trials"] / error["trials"]
    return protocol["trials"] * protocol["steps"] / (protocol["seconds"] + extra)


def peak_rss_mb() -> float:
    """This process's peak resident memory since it started its program (VmHWM; ru_maxrss would carry a
    forked parent's peak across exec)."""
    try:
        with open("/proc/self/status") as status:
            return next(int(line.split()[1]) for line in status if line.startswith("VmHWM:")) / 1024
    except (OSError, StopIteration):  # not Linux
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def protocol_in_child(settings: BenchSettings) -> dict:
    """:func:`protocol_run` in a fresh Python process (its peak RSS is the protocol's alone)."""
    import subprocess
    from pathlib import Path
    root = str(Path(__file__).resolve().parents[2])
    code = ("import json, sys; from rhi.master.bench.settings import BenchSettings; from rhi.master.bench.protocol import protocol_run; "
            "print(json.dumps(protocol_run(BenchSettings(**json.loads(sys.argv[1])))))")
    given = {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(settings).items()}
    given["presets"] = [tuple(p) for p in given["presets"]]
    child = subprocess.run([sys.executable, "-c", code, json.dumps(given)], capture_output=True, text=True,
                           env={**os.environ, "PYTHONPATH": root + os.pathsep + os.environ.get("PYTHONPATH", "")})
    if child.returncode:
        raise RuntimeError(f"the fast-mode protocol run failed: {child.stderr.strip().splitlines()[-1:]}")
    return json.loads(child.stdout.strip().splitlines()[-1])


def fast_error(settings: BenchSettings) -> dict:
    """Final drift of the fast mode against the exact integrator, trained default conv decoder (if cached)."""
    from rhi.master.decoders.cache import checkpoint_path
    from rhi.master.decoders.training import load_decoder
    config = configuration.load(overrides={"experiment.steps": settings.error_steps, "experiment.decoders": ["conv"],
                                           "experiment.trials": settings.error_trials})
    if settings.error_model == "untrained":  # smoke tests: tiny, strong drive, frequent touches
        config = configuration.load(overrides={
            "experiment.steps": settings.error_steps, "experiment.decoders": ["conv"], "experiment.resolution": 32,
            "experiment.trials": settings.error_trials, "decoder.visual_variance": 1e-4, "stimulus.period": 0.4})
        model, source = untrained("tiny", 32, settings.seed), "untrained tiny (smoke test)"
    else:
        source = settings.error_checkpoint or checkpoint_path("conv", config)
        if not os.path.isfile(source):
            return {"skipped": f"no trained default conv decoder at {source}: run `rhi experiment` once "
                               "or name one with --checkpoint"}
        model = load_decoder(source, config["experiment"]["resolution"])
    threads = settings.threads or available_cores()
    trials = experiment.plan(config)
    exact, exact_s = timed(lambda: experiment.run_batch(Decoder(optimised(model), threads=threads), trials, config))
    decoder = LinearisedDecoder(model, relinearise_tolerance=settings.tolerance, threads=threads)
    fast, fast_s = timed(lambda: experiment.run_batch(decoder, trials, config))
    drift_exact = experiment.measures(exact)["drift_cm"][-1]
    drift_fast = experiment.measures(fast)["drift_cm"][-1]
    error = np.abs(drift_fast - drift_exact)
    largest = float(np.abs(drift_exact).max())
    return {"decoder": source, "tolerance_deg": settings.tolerance, "trials": len(trials),
            "steps": settings.error_steps,
            "exact_reference": "Decoder on the optimised copy (written-out JVPs, channels-last; float rounding)",
            "drift_exact_cm": drift_exact.tolist(), "drift_fast_cm": drift_fast.tolist(),
            "max_error_cm": float(error.max()), "largest_drift_cm": largest,
            "relative_error": float(error.max()) / largest if largest > 0 else 0.0,
            "bound_met": bool(error.max() <= 0.01 * largest),
            "relinearisations_per_trial": float(decoder.relinearisations.mean()),
            "decoder_points_per_trial": decoder.decoder_points / len(trials), "call_sizes": decoder.call_sizes,
            "exact_s": exact_s, "fast_s": fast_s, "speedup": exact_s / fast_s}
