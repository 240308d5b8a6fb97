"""``rhi bench --training``: samples per second of a decoder's training step, and where the step's time goes.

One training step of :func:`rhi.components.vision.training.train` (the loss of ``batch_loss``, its
backward pass, the Adam step, and the batch gathered from the rendered data set) is timed phase by
phase on camera images, for each decoder kind, in two ways:

- ``before``: the plain path as it was before the paper preset's settings existed: contiguous
  layout, Adam's for-loop step, and (VAE) the encoder's ReLU before its max-pool;
- ``after``: the settings the configuration gives (by default the paper preset's, master/config/presets/paper_256.toml):
  its batch size, ``channels_last``, ``fused_adam``.

Both wall time and CPU time (user + system of this process) are reported: on a machine shared with
other work the wall time grows with the load while the CPU time per sample barely moves, so
CPU seconds per sample / threads projects the rate on a quiet machine (docs/performance.md).

Example::

    rows = training_rates(configuration.load(preset_name="paper"), steps=3)
    rows["conv"]["after"]["samples_per_s"]
"""
from __future__ import annotations

import dataclasses
import os
import time

import numpy as np
import torch
from torch import nn

from rhi.components.vision.component import available_cores
from rhi.components.vision.networks import build
from rhi.components.vision.training import batch_loss
from rhi.master.decoders import training_data
from rhi.master.decoders.training import train_settings

PHASES = ("data", "encoder", "decoder_and_loss", "backward", "optimiser")
BEFORE_BATCH = 32  # the batch size of the earlier measurements (CHANGELOG.md)


def relu_before_pool(model) -> None:
    """The VAE encoder's stages as they were before: Conv, ReLU, MaxPool (the same function, ReLU at full size)."""
    if model.encoder is None:
        return
    layers = list(model.encoder.convolutions)
    for start in range(0, len(layers), 3):  # Conv, MaxPool, ReLU -> Conv, ReLU, MaxPool
        layers[start + 1], layers[start + 2] = layers[start + 2], layers[start + 1]
    model.encoder.convolutions = nn.Sequential(*layers)


def step_rates(kind: str, settings, images: torch.Tensor, inputs: torch.Tensor, steps: int, before: bool) -> dict:
    """Seconds per training step, by phase (wall), and the step's wall and CPU time, after one warm-up step."""
    torch.manual_seed(settings.seed)
    model = build(kind, settings.preset, settings.resolution)
    if before:
        relu_before_pool(model)
    elif settings.channels_last:
        model = model.to(memory_format=torch.channels_last)
    fused = {"fused": True} if settings.fused_adam and not before else {}
    optimiser = torch.optim.Adam(model.parameters(), lr=settings.lr, **fused)
    generator = torch.Generator().manual_seed(settings.seed)
    encoder_s = [0.0]
    if model.encoder is not None:
        began = {}
        model.encoder.register_forward_pre_hook(lambda *_: began.__setitem__("t", time.perf_counter()))
        model.encoder.register_forward_hook(
            lambda *_: encoder_s.__setitem__(0, encoder_s[0] + time.perf_counter() - began["t"]))
    model.train()
    phases = dict.fromkeys(PHASES, 0.0)
    wall = cpu = 0.0
    for step in range(steps + 1):
        if step == 1:  # the first step warms up (kernels, allocations) and is not counted
            phases, encoder_s[0] = dict.fromkeys(PHASES, 0.0), 0.0
            wall, cpu = time.perf_counter(), time.process_time()
        t0 = time.perf_counter()
        batch = torch.randperm(len(inputs), generator=generator)[:settings.batch_size]
        x, y = inputs[batch], images[batch]
        t1 = time.perf_counter()
        loss = batch_loss(model, x, y, settings, generator)
        t2 = time.perf_counter()
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        t3 = time.perf_counter()
        optimiser.step()
        t4 = time.perf_counter()
        for name, seconds in (("data", t1 - t0), ("decoder_and_loss", t2 - t1), ("backward", t3 - t2),
                              ("optimiser", t4 - t3)):
            phases[name] += seconds
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    phases["encoder"] = encoder_s[0]
    phases["decoder_and_loss"] -= encoder_s[0]
    threads = torch.get_num_threads()
    return {"batch_size": settings.batch_size, "steps": steps, "threads": threads,
            "channels_last": settings.channels_last and not before, "fused_adam": bool(fused),
            "encoder_order": "conv-relu-pool" if before else "conv-pool-relu",
            "step_s": wall / steps, "cpu_s_per_step": cpu / steps,
            "samples_per_s": settings.batch_size * steps / wall,
            "samples_per_cpu_s": settings.batch_size * steps / cpu,
            "phase_s": {name: seconds / steps for name, seconds in phases.items()}}


def training_rates(config: dict, steps: int = 3, threads: int = 0, kinds=("conv", "vae")) -> dict:
    """``before`` and ``after`` rows (:func:`step_rates`) per decoder kind, for the ``[train]`` settings of ``config``
    at its resolution, on camera images of random poses (as many as four batches)."""
    settings = train_settings(config)
    torch.set_num_threads(threads or available_cores())
    data = training_data.generate(4 * settings.batch_size, settings.resolution, settings.seed,
                                  blur=config["camera"]["blur"])
    images = torch.from_numpy(data.images)
    inputs = torch.from_numpy((data.poses - np.asarray(data.rest_pose)) / np.asarray(data.half_ranges)).float()
    rows = {}
    for kind in kinds:
        plain = dataclasses.replace(settings, batch_size=BEFORE_BATCH)
        rows[kind] = {"before": step_rates(kind, plain, images, inputs, steps, before=True),
                      "after": step_rates(kind, settings, images, inputs, steps, before=False)}
        rows[kind]["speedup"] = rows[kind]["after"]["samples_per_s"] / rows[kind]["before"]["samples_per_s"]
    return {"preset": settings.preset, "resolution": settings.resolution, "load_average": list(os.getloadavg()),
            "decoders": rows}


def table(report: dict) -> str:
    """The training rates for people."""
    lines = [f"training step, {report['preset']} decoders at {report['resolution']} px (load average "
             f"{report['load_average'][0]:.1f}):",
             f"  {'decoder':8s}{'path':8s}{'batch':>6s}{'samples/s':>11s}{'per CPU-s':>11s}  "
             + "".join(f"{name:>18s}" for name in PHASES) + "  (ms per step)"]
    for kind, rows in report["decoders"].items():
        for path in ("before", "after"):
            row = rows[path]
            lines.append(f"  {kind:8s}{path:8s}{row['batch_size']:6d}{row['samples_per_s']:11.1f}"
                         f"{row['samples_per_cpu_s']:11.1f}  "
                         + "".join(f"{1000 * row['phase_s'][name]:18.0f}" for name in PHASES))
        lines.append(f"  {kind}: {rows['speedup']:.2f}x")
    return "\n".join(lines)
