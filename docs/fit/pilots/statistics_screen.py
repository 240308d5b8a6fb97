"""A screen of candidate statistics for the group recovery at n = 20 (docs/fit.md, "Which statistic carries Σv's
spread"), on the *training* studies of group_recovery_n20_combined_1000.toml alone: its 100 held-out studies are not
read. For each data file (a set of statistics over the same two cells), the estimator of that fit's settings is
trained on 800 of the 1000 training studies and scored on the other 200 (r of the true values with the posterior
medians, 200 samples each, in the inference space), twice (the last 200 held back, then the first 200); the mean of
the two folds is written. The simulations are that fit's own (``rhi fit ... --out DIR`` leaves them in
DIR/simulations), so no trial runs. Run (about 4 min on 2 cores):
    python docs/fit/pilots/statistics_screen.py DIR/simulations OUT.csv docs/fit/group_recovery_n20_combined.csv \
        docs/fit/pilots/screen_*.csv
"""
import sys
from pathlib import Path

import numpy as np
import torch

from rhi.master.fit import inference, memory
from rhi.master.fit.calibration import recovery
from rhi.master.fit.data import read_data
from rhi.master.fit.plan import read_plan
from rhi.master.fit.priors import draw_participants
from rhi.master.fit.simulate import participants_sweep, simulated_statistics
from rhi.master.sweeps.folder import read_records

FIT = Path(__file__).resolve().parent.parent / "group_recovery_n20_combined_1000.toml"
FOLDS = ((800, 1000), (0, 200))  # the scored training studies of each fold


def screen(simulations: Path, data_path: str) -> tuple[list[str], int, np.ndarray]:
    """The parameters' names, the number of statistics, and each fold's r per parameter (folds, parameters)."""
    data = read_data(data_path)
    plan = read_plan(FIT, data)
    drawn = draw_participants(plan.parameters, plan.settings)
    sweep = participants_sweep(plan, drawn, "prior")
    records = read_records(simulations, sweep)
    training = plan.settings["simulations"]
    x, theta = simulated_statistics(plan, sweep, records, data, "prior")[:training], drawn[:training]
    valid = np.all(np.isfinite(x), axis=1)
    folds = []
    for first, last in FOLDS:
        scored = np.zeros(training, dtype=bool)
        scored[first:last] = True
        posterior = memory.train(plan, theta[valid & ~scored], x[valid & ~scored])
        rows = np.flatnonzero(valid & scored)
        samples = np.stack([inference.sample(posterior, x[row], 200, 7 + int(row)) for row in rows])
        folds.append(recovery(samples, theta[rows])["correlation"])
    return [p.key for p in plan.parameters], x.shape[1], np.array(folds)


def main(simulations: str, out: str, *data_paths: str) -> None:
    torch.set_num_threads(2)
    lines = []
    for path in data_paths:
        names, count, folds = screen(Path(simulations), path)
        if not lines:
            lines.append("data,statistics," + ",".join(f"{name}_r" for name in names))
        lines.append(f"{Path(path).name},{count}," + ",".join(f"{r:.3f}" for r in folds.mean(axis=0)))
    with open(out, "w") as file:
        file.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main(*sys.argv[1:])
