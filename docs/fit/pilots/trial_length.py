"""The pilot behind group_recovery_n20_30s.toml (docs/fit.md, "The paper's trial length"): how each statistic of one
participant depends on the three parameters as the trial goes on. 48 individuals, no spread, each parameter drawn
log-uniformly over its median's prior in group_recovery_n20_combined_1000.toml (Σv 5–80, Σp 0.5–2, γ0 0.003–0.1),
seed 5, the paper's model, Left, sync and async, one 30 s trial each (1500 steps, the batched arm, 64x64). Each
statistic's log |value| is regressed on the three standardised log-parameters (least squares with an intercept);
the standardised coefficients and R² are written to trial_length.csv. It scores no recovery. Run (about 40 CPU-s):
    python docs/fit/pilots/trial_length.py docs/fit/pilots/trial_length.csv
"""
import sys

import numpy as np
import torch

from rhi import load_config
from rhi.master.sweeps import plan as sweeps
from rhi.master.sweeps.runner import run_in_memory

PROBES = [2.0, 4.0, 6.0, 12.0, 20.0]
STATISTICS = [f"drift_at_{t:g}s_cm" for t in PROBES] + ["drift_cm", "force_n", "gamma_final"]


def main(out: str) -> None:
    torch.set_num_threads(1)
    rng = np.random.default_rng(5)
    n = 48
    visual = np.exp(rng.uniform(np.log(5), np.log(80), n))
    proprioceptive = np.exp(rng.uniform(np.log(0.5), np.log(2), n))
    gamma0 = np.exp(rng.uniform(np.log(0.003), np.log(0.1), n))
    base = load_config()
    base["experiment"].update(steps=1500, conditions=["left"], stimulations=["sync", "async"], body="batched",
                              trials=1, probe_times=PROBES)
    points = [{"decoder.visual_variance": float(a), "brain.proprioceptive_variance": float(b), "brain.gamma0": float(c)}
              for a, b, c in zip(visual, proprioceptive, gamma0)]
    sweep = sweeps.build(base, points, workers=1, points_per_batch=n)
    records = run_in_memory(sweep)
    factors = np.log(np.column_stack([visual, proprioceptive, gamma0]))
    factors = (factors - factors.mean(0)) / factors.std(0)
    design = np.column_stack([factors, np.ones(n)])
    lines = ["stimulation,statistic,visual_variance,proprioceptive_variance,gamma0,r2,median"]
    for stimulation in ("sync", "async"):
        for statistic in STATISTICS:
            value = np.full(n, np.nan)
            for trial in sweep.trials:
                if trial.stimulation == stimulation:
                    value[trial.point] = records[trial.id]["outcome"][statistic]
            target = np.log(np.abs(value))
            target = (target - target.mean()) / target.std()
            coefficients, *_ = np.linalg.lstsq(design, target, rcond=None)
            r2 = 1 - ((design @ coefficients - target) ** 2).sum() / (target ** 2).sum()
            lines.append(f"{stimulation},{statistic},{coefficients[0]:.2f},{coefficients[1]:.2f},{coefficients[2]:.2f},"
                         f"{r2:.3f},{np.median(value):.4g}")
    with open(out, "w") as file:
        file.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main(sys.argv[1])
