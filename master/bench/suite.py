"""``rhi bench [--json]``: agent-steps per second of each way to run the protocol, and why.

An agent-step is one trial advanced one communication step, everything included (body,
camera, stimulus, rubber arm, decoder, brain, master). Measured per preset (paper: 256x256
and the paper's decoder; default: 64x64 and the default decoder), with UNTRAINED seeded
decoders of the right architecture (speed does not depend on the weights):

- baseline: :class:`master.bench.baseline.PaperStyleAgent`, one trial the way the released agent runs;
- exact_single: this project's integrator, B = 1 through :func:`master.cosim.simulate`;
- exact_batched: all ``batch`` trials of the protocol in lockstep, one decoder call per step;
- exact_batched_optimised: the same with the decoder's JVPs written out, in channels-last layout;
- fast: the linearised decoder (:mod:`components.vision.fast`), batched.

Each is timed after a warm-up (the initialization's decoder call, and a 2-step probe run
that sizes the measured run to ``budget_s``). Also: the decoder's FLOPs per agent-step
(analytic from the layer shapes, MACs x 2, checked against torch's FlopCounterMode, which
also counts the JVP step), the achieved FLOP/s against a measured fp32 matmul peak, each
component's share of the step, the master's per-step time against fmpy.simulate_fmu on the
same body FMU (both set the inputs and read the outputs every step), the whole paper protocol
in fast mode (in a child process, for its peak memory), the fast mode's drift error against
the exact integrator with a trained default decoder when one is cached (docs/performance.md), and
the protocol as a sweep on the local pool against the same trials in lockstep
(:mod:`master.bench.sweep_rate`).
"""
from __future__ import annotations

import json
import os
import platform
import resource
import sys
import time
from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch.utils.flop_counter import FlopCounterMode

from components.body import kinematics
from components.vision.component import Decoder, GenerativeModel, available_cores
from components.vision.fast import DEFAULT_TOLERANCE, LinearisedDecoder
from components.vision.optimised import optimised
from components.vision.networks import build
from master.experiment import config as configuration
from master import experiment
from master.bench.baseline import PaperStyleAgent
from master.bench.default_run import default_run
from master.bench.report import targets
from master.bench.sweep_rate import sweep_rate
from master.experiment.training_data import HALF_RANGES


@dataclass(frozen=True)
class BenchSettings:
    presets: tuple = (("paper", 256), ("default", 64))  # (network preset, resolution)
    batch: int = 60              # trials in lockstep: the whole protocol (2 decoders x 3 x 2 x 5)
    max_steps: int = 50          # measured steps per mode at most ...
    min_steps: int = 2           # ... and at least
    budget_s: float = 8.0        # aimed-at measuring time per mode
    protocol_steps: int = 1500   # the fast-mode run of the whole paper protocol
    protocol_preset: tuple = ("paper", 256)
    protocol_trained: str = "paper"  # whose cached trained decoders run the protocol when both are cached:
                                     # "paper" (--preset paper), "quick" (--quick); "": always the untrained one
    tolerance: float = DEFAULT_TOLERANCE
    error_trials: int = 5        # per condition x stimulation, for the fast mode's drift error (as in one
                                 # decoder's half of the protocol)
    error_steps: int = 1500
    error_model: str = "cached"  # cached: the trained default conv decoder (or error_checkpoint); untrained: tiny
    error_checkpoint: str = ""   # a trained conv checkpoint at the default resolution, instead of the cached one
    fmu_steps: int = 300
    matmul_size: int = 2048
    threads: int = 0             # torch threads; 0: the cores this process may use
    seed: int = 0
    default_run: bool = True     # time `rhi experiment` from an empty decoder cache (master/bench/default_run.py)
    sweep_preset: tuple = ("default", 64)  # the sweep against lockstep (master/bench/sweep_rate.py)
    sweep_trials: int = 5        # per decoder x condition x stimulation: 60 trials, the whole protocol
    sweep_steps: int = 1500
    sweep_trained: bool = True   # the trained default decoders (shipped) rather than untrained ones
    sweep_workers: int = 0       # the sweep's local pool; 0: one per usable core


QUICK = BenchSettings(presets=(("tiny", 32),), batch=6, max_steps=3, budget_s=0.5, protocol_steps=10,
                      protocol_preset=("tiny", 32), protocol_trained="", error_trials=1, error_steps=30,
                      error_model="untrained", fmu_steps=20, matmul_size=256, default_run=False,
                      sweep_preset=("tiny", 32), sweep_trials=1, sweep_steps=10, sweep_workers=1, sweep_trained=False)


def untrained(preset: str, resolution: int, seed: int) -> GenerativeModel:
    torch.manual_seed(seed)
    return GenerativeModel(build("conv", preset, resolution).decoder, kinematics.REST_POSE, HALF_RANGES)


def protocol_config(resolution: int, steps: int, **overrides) -> dict:
    return configuration.load(overrides={"experiment.resolution": resolution, "experiment.steps": steps,
                                         "experiment.decoders": ["conv", "vae"], **overrides})


def protocol_trials(config: dict, batch: int) -> list:
    """``batch`` trials of the protocol's plan, spread over it (all 60 when batch is 60)."""
    trials = experiment.plan(config)
    return [trials[i] for i in np.linspace(0, len(trials) - 1, batch).round().astype(int)]


# -- counting -------------------------------------------------------------------------------------
def analytic_flops(decoder: torch.nn.Module, resolution: int) -> int:
    """Forward FLOPs of one trial from the layer shapes: 2 x MACs of every Linear, Conv2d, ConvTranspose2d."""
    total, hooks = [0], []

    def count(module, inputs, output):
        if isinstance(module, torch.nn.Linear):
            total[0] += 2 * module.in_features * module.out_features
        elif isinstance(module, torch.nn.ConvTranspose2d):  # every input pixel meets every kernel tap
            total[0] += 2 * module.in_channels * module.out_channels * np.prod(module.kernel_size) * \
                np.prod(inputs[0].shape[2:])
        elif isinstance(module, torch.nn.Conv2d):  # every output pixel meets every kernel tap
            total[0] += 2 * module.in_channels * module.out_channels * np.prod(module.kernel_size) * \
                np.prod(output.shape[2:])

    for module in decoder.modules():
        hooks.append(module.register_forward_hook(count))
    with torch.no_grad():
        decoder(torch.zeros(1, 2))
    for hook in hooks:
        hook.remove()
    return int(total[0])


def counted_flops(function) -> int:
    with FlopCounterMode(display=False) as counter:
        function()
    return int(counter.get_total_flops())


def decoder_flops(model: GenerativeModel, agent: PaperStyleAgent) -> dict:
    """FLOPs per trial: forward (analytic and counted), the exact step (JVPs), the baseline agent's step."""
    mu = torch.tensor([kinematics.REST_POSE], dtype=torch.float32)

    def forward_backward():
        inpt, output = agent.visual_forward(mu.numpy())
        output.backward(torch.ones_like(output), retain_graph=True)

    fast = optimised(model)
    with torch.no_grad():
        forward = counted_flops(lambda: model(mu))
        step = counted_flops(lambda: model.predict_with_jacobian(mu))
        written_out = counted_flops(lambda: fast.predict_with_jacobian(mu))
    analytic = analytic_flops(model.decoder, model.resolution)
    return {"method": "forward: analytic from layer shapes (2 x MACs of Linear/Conv/ConvTranspose); "
                      "steps: torch.utils.flop_counter.FlopCounterMode; optimised: the useful 3 x forward "
                      "(its sub-pixel last layer computes more, counted in optimised_step_counted)",
            "forward_per_trial": analytic, "forward_per_trial_counted": forward, "exact_step_per_trial": step,
            "optimised_step_per_trial": 3 * analytic, "optimised_step_counted": written_out,
            "baseline_step_per_trial": counted_flops(forward_backward)}


def matmul_peak(size: int, repeats: int = 10) -> dict:
    """Dense fp32 matmul FLOP/s: best of ``repeats`` torch.mm of size x size."""
    a, b = torch.randn(size, size), torch.randn(size, size)
    torch.mm(a, b)
    best = min(timed(lambda: torch.mm(a, b))[1] for _ in range(repeats))
    return {"size": size, "seconds": best, "flop_per_s": 2 * size ** 3 / best}


def timed(function):
    began = time.perf_counter()
    value = function()
    return value, time.perf_counter() - began


# -- modes ----------------------------------------------------------------------------------------
def system_run(make_decoder, trials, resolution: int, steps: int) -> dict:
    """One run through the master; rates from the stepping time (setup and initialization excluded)."""
    result = experiment.run_batch(make_decoder(), trials, protocol_config(resolution, steps))
    t = result.timings
    stepping = t["total_s"] - t["setup_s"]
    components = {key[len("step_s."):]: value for key, value in t.items() if key.startswith("step_s.")}
    return {"trials": len(trials), "steps": steps, "seconds": stepping, "setup_s": t["setup_s"],
            "agent_steps_per_s": len(trials) * steps / stepping,
            "component_s": components, "share": {k: v / stepping for k, v in components.items()},
            "master_overhead_s_per_step": t["master_overhead_s"] / steps,
            "decoder_s": components["decoder"]}


def sized_run(make_decoder, trials, resolution: int, settings: BenchSettings) -> dict:
    """A 2-step probe (the warm-up), then a run sized to the time budget (or the probe if that is all it allows)."""
    probe = system_run(make_decoder, trials, resolution, settings.min_steps)
    per_step = probe["seconds"] / probe["steps"]
    steps = int(np.clip(settings.budget_s / per_step, settings.min_steps, settings.max_steps))
    return probe if steps <= settings.min_steps else system_run(make_decoder, trials, resolution, steps)


def baseline_run(model, trial, resolution: int, settings: BenchSettings) -> dict:
    config = protocol_config(resolution, settings.max_steps)
    PaperStyleAgent(model, trial, config).run(settings.min_steps)  # warm-up
    probe = PaperStyleAgent(model, trial, config)
    probe.run(settings.min_steps)
    steps = int(np.clip(settings.budget_s * settings.min_steps / probe.step_seconds, settings.min_steps,
                        settings.max_steps))
    agent = PaperStyleAgent(model, trial, config)
    agent.run(steps)
    return {"trials": 1, "steps": steps, "seconds": agent.step_seconds, "setup_s": agent.setup_seconds,
            "agent_steps_per_s": steps / agent.step_seconds, "decoder_s": agent.decoder_seconds,
            "share": {"decoder": agent.decoder_seconds / agent.step_seconds}}


def with_flops(row: dict, flops_per_agent_step: int, peak: float) -> dict:
    """Decoder FLOPs of the run, the FLOP/s achieved inside the decoder and its fraction of the matmul peak."""
    flops = flops_per_agent_step * row["trials"] * row["steps"]
    return {**row, "decoder_flops": flops, "decoder_flop_per_s": flops / row["decoder_s"],
            "peak_fraction": flops / row["decoder_s"] / peak}


def preset_rows(preset: str, resolution: int, settings: BenchSettings, peak: float) -> dict:
    model = untrained(preset, resolution, settings.seed)
    threads = settings.threads or available_cores()
    config = protocol_config(resolution, settings.max_steps)
    batch = protocol_trials(config, settings.batch)
    flops = decoder_flops(model, PaperStyleAgent(model, batch[0], config))
    fast_model = optimised(model)
    rows = {
        "baseline": with_flops(baseline_run(model, batch[0], resolution, settings),
                               flops["baseline_step_per_trial"], peak),
        "exact_single": with_flops(sized_run(lambda: Decoder(model, threads=threads), batch[:1], resolution,
                                             settings), flops["exact_step_per_trial"], peak),
        "exact_batched": with_flops(sized_run(lambda: Decoder(model, threads=threads), batch, resolution,
                                              settings), flops["exact_step_per_trial"], peak),
        "exact_batched_optimised": with_flops(sized_run(lambda: Decoder(fast_model, threads=threads), batch,
                                                        resolution, settings), flops["optimised_step_per_trial"], peak),
        "fast": sized_run(lambda: LinearisedDecoder(fast_model, relinearise_tolerance=settings.tolerance,
                                                    threads=threads, fast_layout=False), batch, resolution, settings),
    }
    return {"preset": preset, "resolution": resolution, "weights": f"untrained, torch seed {settings.seed}",
            "flops": flops, "modes": rows}


def run_suite(settings: BenchSettings = BenchSettings()) -> dict:
    """Every measurement; the dictionary ``rhi bench --json`` prints."""
    threads = settings.threads or available_cores()
    torch.set_num_threads(threads)
    began, load_before = time.perf_counter(), os.getloadavg()
    report = {"settings": {**asdict(settings), "tolerance_unit": "deg"}, "machine": machine(threads),
              "matmul_peak": matmul_peak(settings.matmul_size)}
    peak = report["matmul_peak"]["flop_per_s"]
    report["presets"] = {f"{preset}-{res}": preset_rows(preset, res, settings, peak)
                         for preset, res in settings.presets}
    report["protocol_fast"] = protocol_in_child(settings)
    report["fast_error"] = fast_error(settings)
    report["protocol_fast"]["projected_agent_steps_per_s"] = (
        None if report["protocol_fast"]["trained"] else projected(report["protocol_fast"], report["fast_error"],
                                                                  settings))
    report["master_overhead"] = master_overhead(settings.fmu_steps)
    report["default_run"] = default_run() if settings.default_run else {"skipped": "default_run = False"}
    report["sweep_rate"] = sweep_rate(settings)
    report["memory"] = {"bench_peak_rss_mb": peak_rss_mb(),
                        "protocol_peak_rss_mb": report["protocol_fast"]["peak_rss_mb"]}
    report["machine"]["load_average_before"], report["machine"]["load_average_after"] = load_before, os.getloadavg()
    report["matmul_peak_at_end"] = matmul_peak(settings.matmul_size)  # shows how steady the machine was
    report["bench_seconds"] = time.perf_counter() - began
    report["targets"] = targets(report)
    return report


# -- the rest of the suite ------------------------------------------------------------------------
def machine(threads: int) -> dict:
    import fmpy
    import pymunk
    import scipy
    info = {}
    with open("/proc/cpuinfo") as file:
        for line in file:
            key, _, value = line.partition(":")
            if key.strip() in ("model name", "flags") and key.strip() not in info:
                info[key.strip()] = value.strip()
    flags = set(info.get("flags", "").split())
    return {"cpu": info.get("model name", platform.processor()), "cores": os.cpu_count(),
            "usable_cores": available_cores(), "torch_threads": threads,
            "cpu_flags": {f: f in flags for f in ("avx2", "fma", "avx512f", "avx512_bf16", "amx_bf16")},
            "python": platform.python_version(), "torch": torch.__version__, "numpy": np.__version__,
            "scipy": scipy.__version__, "pymunk": pymunk.version, "fmpy": fmpy.__version__}


def trained_protocol(settings: BenchSettings) -> tuple[dict, dict] | None:
    """The configuration of ``protocol_trained`` (its protocol, ``protocol_steps`` steps) and the cached trained
    decoders it names, if every one of them is in the cache; else None."""
    if not settings.protocol_trained:
        return None
    from master.experiment.decoders import checkpoint_path
    quick = settings.protocol_trained == "quick"
    config = configuration.load(quick=quick, preset_name=None if quick else settings.protocol_trained,
                                overrides={"experiment.steps": settings.protocol_steps})
    paths = {kind: checkpoint_path(kind, config) for kind in config["experiment"]["decoders"]}
    return (config, paths) if all(os.path.isfile(path) for path in paths.values()) else None


def _trained_protocol(config: dict, paths: dict, threads: int) -> dict:
    """The protocol as `rhi experiment` runs it once its decoders are cached: each decoder's trials in one lockstep
    batch through the decoder component the configuration makes (the paper preset: the fast mode); the time
    includes loading each decoder."""
    from master.experiment.decoders import decoder_component
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


def _protocol(settings: BenchSettings) -> dict:
    """The whole protocol in fast mode (run in a child: its peak RSS is the run's): with the trained decoders of
    ``protocol_trained`` when they are cached, else with an untrained one at ``protocol_preset`` (whose rate
    :func:`projected` corrects with the decoder calls of a trained decoder, replayed)."""
    threads = settings.threads or available_cores()
    trained = trained_protocol(settings)
    if trained is not None:
        return _trained_protocol(*trained, threads)
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
    """:func:`_protocol` in a fresh Python process (its peak RSS is the protocol's alone)."""
    import subprocess
    from pathlib import Path
    root = str(Path(__file__).resolve().parents[2])
    code = ("import json, sys; from master.bench.suite import BenchSettings, _protocol; "
            "print(json.dumps(_protocol(BenchSettings(**json.loads(sys.argv[1])))))")
    given = {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(settings).items()}
    given["presets"] = [tuple(p) for p in given["presets"]]
    child = subprocess.run([sys.executable, "-c", code, json.dumps(given)], capture_output=True, text=True,
                           env={**os.environ, "PYTHONPATH": root + os.pathsep + os.environ.get("PYTHONPATH", "")})
    if child.returncode:
        raise RuntimeError(f"the fast-mode protocol run failed: {child.stderr.strip().splitlines()[-1:]}")
    return json.loads(child.stdout.strip().splitlines()[-1])


def fast_error(settings: BenchSettings) -> dict:
    """Final drift of the fast mode against the exact integrator, trained default conv decoder (if cached)."""
    from master.experiment.decoders import checkpoint_path
    from master.experiment.training import load_decoder
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


OUTPUTS = ("q_shoulder", "q_elbow", "hand_x", "hand_y", "force_x", "force_y")


def master_overhead(steps: int, step_size: float = 0.02) -> dict:
    """Per-step wall time of the same body FMU (B = 1) under fmpy.simulate_fmu and under this master driving the
    FMUComponent adapter alone, from time stamps after each step (setup excluded), best of three interleaved rounds."""
    import tempfile
    from pathlib import Path

    from fmpy import read_model_description, simulate_fmu

    from components.body.contract import BODY_CONTRACT
    from components.fmu import FMUComponent, extracted, guard_library
    from master.cosim import simulate
    from master.export.body import build_fmu
    from master.cosim import System

    # Both set the two inputs (held at 0) before every step and read the six outputs after it.
    signal = np.array([(0.0, 0.0, 0.0), (steps * step_size, 0.0, 0.0)],
                      dtype=[("time", float), ("u_shoulder", float), ("u_elbow", float)])

    def under_fmpy(stamp):
        simulate_fmu(unzipdir, stop_time=steps * step_size, step_size=step_size, output_interval=step_size,
                     input=signal, output=list(OUTPUTS), model_description=description, validate=False,
                     step_finished=lambda *_: stamp() or True)

    def under_master(stamp):
        timings.append(simulate(System([FMUComponent(path, "body", BODY_CONTRACT)], []), steps * step_size, step_size,
                                record=[f"body.{o}" for o in OUTPUTS], progress=lambda *_: stamp()).timings)

    def per_step(run):
        stamps = []
        run(lambda: stamps.append(time.perf_counter()))
        return (stamps[-1] - stamps[0]) / (len(stamps) - 1)

    saved, timings = list(sys.path), []  # a pythonfmu FMU prepends its resources to sys.path
    with tempfile.TemporaryDirectory(prefix="rhi_bench_") as folder:
        path = str(build_fmu(Path(folder) / "Body.fmu", "native"))
        description = read_model_description(path)
        unzipdir = extracted(path)
        guard_library(unzipdir, description.coSimulation.modelIdentifier)
        try:  # interleaved, so that a slow patch of the machine hits both alike
            fmpy_step, master_step = np.min([[per_step(under_fmpy), per_step(under_master)] for _ in range(3)],
                                            axis=0).tolist()
        finally:
            sys.path[:] = saved
    return {"fmu": "native body (pythonfmu)", "steps": steps, "fmpy_step_s": fmpy_step, "master_step_s": master_step,
            "wall_ratio": master_step / fmpy_step,
            "of_which_master_loop_s": min(t["master_overhead_s"] for t in timings) / steps,
            "of_which_adapter_and_fmu_s": min(t["step_s.body"] for t in timings) / steps}
