"""``rhi bench [--json]``: agent-steps per second of each way to run the protocol, and why.

An agent-step is one trial advanced one communication step, everything included (body,
camera, stimulus, rubber arm, decoder, brain, master). Measured per preset (paper: 256x256
and the paper's decoder; default: 64x64 and the default decoder), with UNTRAINED seeded
decoders of the right architecture (speed does not depend on the weights):

- baseline: :class:`rhi.master.bench.baseline.PaperStyleAgent`, one trial the way the released agent runs;
- exact_single: this project's integrator, B = 1 through :func:`rhi.master.cosim.simulate`;
- exact_batched: all ``batch`` trials of the protocol in lockstep, one decoder call per step;
- exact_batched_optimised: the same with the decoder's JVPs written out, in channels-last layout;
- fast: the linearised decoder (:mod:`rhi.components.vision.fast`), batched.

Each is timed after a warm-up (the initialization's decoder call, and a 2-step probe run
that sizes the measured run to ``budget_s``). Also: the decoder's FLOPs per agent-step
(analytic from the layer shapes, MACs x 2, checked against torch's FlopCounterMode, which
also counts the JVP step), the achieved FLOP/s against a measured fp32 matmul peak, each
component's share of the step, the master's per-step time against fmpy.simulate_fmu on the
same body FMU (both set the inputs and read the outputs every step), the whole paper protocol
in fast mode (in a child process, for its peak memory), the fast mode's drift error against
the exact integrator with a trained default decoder when one is cached (docs/performance.md), and
the protocol as a sweep on the local pool against the same trials in lockstep
(:mod:`rhi.master.bench.sweep_rate`), and the fit's unit of work: CPU-s per simulated 1500-step trial in fit-like
batches, paper's model and causal (:mod:`rhi.master.bench.fit_unit`).
"""
from __future__ import annotations

import os
import platform
import time
from dataclasses import asdict

import numpy as np
import torch
from torch.utils.flop_counter import FlopCounterMode

from rhi.components.body import kinematics
from rhi.components.vision.component import Decoder, GenerativeModel, available_cores
from rhi.components.vision.fast import LinearisedDecoder
from rhi.components.vision.optimised import optimised
from rhi.master.tasks import illusion as experiment
from rhi.master.bench.baseline import PaperStyleAgent
from rhi.master.bench.fmu_overhead import master_overhead
from rhi.master.bench.protocol import fast_error, peak_rss_mb, projected, protocol_in_child
from rhi.master.bench.default_run import default_run
from rhi.master.bench.fit_unit import fit_unit
from rhi.master.bench.report import targets
from rhi.master.bench.settings import BenchSettings, protocol_config, protocol_trials, timed, untrained
from rhi.master.bench.sweep_rate import sweep_rate


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
    """The FLOPs torch's FlopCounterMode counts while ``function()`` runs."""
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
    """The baseline: one trial the way the released agent runs (:class:`~rhi.master.bench.baseline.PaperStyleAgent`),
    after a warm-up, its steps sized to ``settings.budget_s`` by a probe run.

    Returns
    -------
    dict
        ``trials``, ``steps``, ``seconds`` (stepping), ``setup_s``, ``agent_steps_per_s``, ``decoder_s`` and
        ``share`` (the decoder's of the step time).
    """
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
    """Every mode's measurement for one network preset, with an untrained seeded decoder.

    Parameters
    ----------
    preset : str
        The network preset.
    resolution : int
        Image side, px.
    settings : BenchSettings
    peak : float
        The matmul peak, FLOP/s, the decoder's rate is compared with.

    Returns
    -------
    dict
        ``preset``, ``resolution``, ``weights``, ``flops`` (per agent-step) and ``modes``: baseline,
        exact_single, exact_batched, exact_batched_optimised and fast.
    """
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
    report["fit_unit"] = fit_unit(settings)
    report["memory"] = {"bench_peak_rss_mb": peak_rss_mb(),
                        "protocol_peak_rss_mb": report["protocol_fast"]["peak_rss_mb"]}
    report["machine"]["load_average_before"], report["machine"]["load_average_after"] = load_before, os.getloadavg()
    report["matmul_peak_at_end"] = matmul_peak(settings.matmul_size)  # shows how steady the machine was
    report["bench_seconds"] = time.perf_counter() - began
    report["targets"] = targets(report)
    return report


# -- the rest of the suite ------------------------------------------------------------------------
def machine(threads: int) -> dict:
    """The machine the bench ran on: CPU model and flags, cores (all and usable), ``threads`` (torch's), and the
    versions of Python and the numeric packages.
    """
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
