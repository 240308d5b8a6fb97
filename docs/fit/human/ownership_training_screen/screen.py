"""The drift's adopted point: the screen of docs/fit.md ("Several studies", the third rule and what ships), from the
1000-study training fit's simulations. Writes this folder's screen.csv (the 30 prior draws nearest the training
statistics, 5 more studies each), checks.csv (20 studies at each candidate), point.csv (the point that ships, in
rhi fit's point.csv form) and estimates.csv (the fit's own, whose intervals the constants table quotes).

Run from the project's folder, with the fit's folder (``rhi fit --data docs/fit/human/training.csv --config
docs/fit/human/ownership_training_judged_1000.toml --out FIT``; 113 min on 2 cores of an AVX2 EPYC):
    python docs/fit/human/ownership_training_screen/screen.py FIT
"""
import csv
import shutil
import sys
from pathlib import Path

import numpy as np

from rhi.master.fit.data import read_data
from rhi.master.fit.memory import simulate
from rhi.master.fit.plan import read_plan
from rhi.master.fit.priors import draw_participants
from rhi.master.fit.run import data_statistic_names, select
from rhi.master.fit.simulate import Pool, participants_sweep, simulate as run_sweep, simulated_statistics

HERE = Path(__file__).resolve().parent
HUMAN = HERE.parent
NEAREST, SCREEN_STUDIES, CHECK_STUDIES = 30, 5, 20
# The constants shipped before (model.md, order of work, step 13), as a point of the fit's seven parameters
SHIPPED = {"population.ownership.coupling_prior.median": 0.189, "population.ownership.coupling_prior.logit_sd": 2.47,
           "population.ownership.realignment_rate.median": 0.998, "population.ownership.realignment_rate.log_sd": 0.0704,
           "ownership.coupling_window_sd": 0.138, "ownership.counter_evidence_leak": 0.936,
           "ownership.proprioceptive_fading_rate": 0.0118}


def standard_errors(observed: np.ndarray, trials: np.ndarray) -> np.ndarray:
    """Each mean's SEM (sd / sqrt n) and each sd's standard error sd / sqrt(2 (n - 1)), the statistics in pairs
    (mean, sd) of one cell."""
    sd = np.repeat(observed[1::2], 2)
    return np.where(np.arange(len(observed)) % 2 == 0, sd / np.sqrt(trials), sd / np.sqrt(2 * (trials - 1)))


def main(fit_folder: Path) -> None:
    data = read_data(str(HUMAN / "training.csv"))
    plan = read_plan(str(HUMAN / "ownership_training_judged_1000.toml"), data)
    drawn = draw_participants(plan.parameters, plan.settings)
    sweep = participants_sweep(plan, drawn, "prior")
    with Pool(None, 1, False) as pool:
        records, ran = run_sweep(sweep, fit_folder / "simulations", pool, "the fit's studies")
    if ran:
        raise SystemExit(f"{fit_folder} is not that fit's folder: {ran} of its studies were missing")
    one_study = simulated_statistics(plan, sweep, records, data, "prior")
    observed = np.asarray(select(data, plan)[0], dtype=float)
    statistic_names = data_statistic_names(data, plan)
    trials = np.array([next(design["experiment.trials"] for part, design in zip(data.parts, plan.designs)
                            if f"[{part.protocol}:" in name) for name in statistic_names])
    errors = standard_errors(observed, trials)

    def worst(statistics):
        return np.abs((statistics - observed) / errors).max(axis=-1)

    near = np.argsort(worst(one_study), kind="stable")[:NEAREST]
    screened = simulate(plan, data, np.repeat(drawn[near], SCREEN_STUDIES, axis=0), "screen")
    means = screened.reshape(NEAREST, SCREEN_STUDIES, -1).mean(axis=1)
    order = np.argsort(worst(means), kind="stable")
    best = int(near[order[0]])
    names = [p.key for p in plan.parameters]
    own = lambda row: {p.key: float(p.from_inference(v)) for p, v in zip(plan.parameters, row)}  # noqa: E731
    with open(HERE / "screen.csv", "w", newline="") as file:
        out = csv.writer(file)
        out.writerow(["draw", "one_study_largest_z", "five_study_largest_z", *names])
        for i in order:
            out.writerow([int(near[i]), f"{worst(one_study[near[i]]):.4g}", f"{worst(means[i]):.4g}",
                          *(f"{v:.6g}" for v in own(drawn[near[i]]).values())])
    with open(fit_folder / "point.csv") as file:
        flow = {row["parameter"]: float(row["value"]) for row in csv.DictReader(file)}
    candidates = {"flow's point": flow, f"draw {best}": own(drawn[best]), "shipped before": SHIPPED}
    with open(HERE / "checks.csv", "w", newline="") as file:
        out = csv.writer(file)
        out.writerow(["candidate", "statistic", "observed", "standard_error", "mean_of_20_studies", "z"])
        largest = {}
        for name, point in candidates.items():
            row = [p.to_inference(point[p.key]) for p in plan.parameters]
            check = simulate(plan, data, np.array([row] * CHECK_STUDIES, dtype=float), "point").mean(axis=0)
            largest[name] = worst(check)
            for statistic, o, e, m in zip(statistic_names, observed, errors, check):
                out.writerow([name, statistic, o, f"{e:.4g}", f"{m:.4g}", f"{(m - o) / e:.3g}"])
    ships = min(largest, key=largest.get)
    print({name: round(float(value), 3) for name, value in largest.items()}, "ships:", ships)
    with open(HERE / "point.csv", "w", newline="") as file:
        out = csv.writer(file)
        out.writerow(["participant", "parameter", "value", "sample", "log_density"])
        for key, value in candidates[ships].items():
            out.writerow(["training", key, f"{value:.6g}", best if ships.startswith("draw") else "", ""])
    shutil.copyfile(fit_folder / "estimates.csv", HERE / "estimates.csv")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
