"""The published numbers' cross-CPU check: the shipped default decoders on a short protocol, and the table of
its outcomes that tests/reference/short_protocol.csv holds (made on the CPU its header names).

    python -m tests.cross_cpu            # print the table made on this CPU
    python -m tests.cross_cpu --write    # replace the shipped reference with it

The protocol is the default one (both decoders, every condition and stimulation) with one trial a cell, run
in each mode for STEPS[mode] steps: the exact decoder (whose arithmetic the cross-CPU bound is about) briefly,
and the fast one (the default run's) for longer, every kernel the default run uses in a fraction of its time.
"""
from __future__ import annotations

import csv
import io
import sys
from pathlib import Path

REFERENCE = Path(__file__).parent / "reference" / "short_protocol.csv"
# Steps per mode: 4 s (two touches) of the exact decoder, 10 s (a third of the 30 s drift) of the fast one.
STEPS = {"exact": 200, "fast": 500}
COLUMNS = ("drift_cm", "force_x_n", "gamma", "mu_shoulder_deg", "mu_elbow_deg")
KEYS = ("mode", "decoder", "condition", "stimulation")


def outcomes() -> list[dict]:
    """Each trial's end-of-trial COLUMNS (floats) with its KEYS, per mode, in the protocol's order."""
    return [row for mode in STEPS for row in mode_outcomes(mode)]


def mode_outcomes(mode: str) -> list[dict]:
    from rhi.master import config as configuration
    from rhi.master.tasks.illusion import runner
    from rhi.master.decoders.cache import checkpoint_path
    from rhi.master.runtime.context import RunContext
    from rhi.master.tasks.illusion.measures import end_of_trial

    config = configuration.load(overrides={"experiment.trials": 1, "experiment.steps": STEPS[mode]})
    kinds = config["experiment"]["decoders"]
    checkpoints = {kind: checkpoint_path(kind, config, must_exist=True) for kind in kinds}
    trials, times, per_step, _, failures = runner.run(config, checkpoints, context=RunContext(processes=1),
                                                      fast={kind: mode == "fast" for kind in kinds})
    assert not failures, failures
    final = end_of_trial(times, per_step)
    return [{"mode": mode, **{key: getattr(trial, key) for key in KEYS[1:]},
             **{name: float(final[name][i]) for name in COLUMNS}} for i, trial in enumerate(trials)]


def table(rows: list[dict]) -> str:
    """The CSV text: a comment naming the CPU, then KEYS + COLUMNS, floats in full (repr) precision."""
    from rhi.master.outputs.provenance import cpu_description

    cpu = cpu_description()
    text = io.StringIO()
    text.write(f"# made on {cpu['model']} (torch kernels {cpu.get('torch_kernels', '?')})\n")
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(KEYS + COLUMNS)
    writer.writerows([[row[key] for key in KEYS] + [repr(row[name]) for name in COLUMNS] for row in rows])
    return text.getvalue()


def read(path: Path = REFERENCE) -> list[dict]:
    lines = [line for line in path.read_text(encoding="utf-8").splitlines() if not line.startswith("#")]
    return [{key: (value if key in KEYS else float(value)) for key, value in row.items()}
            for row in csv.DictReader(lines)]


if __name__ == "__main__":
    text = table(outcomes())
    if "--write" in sys.argv[1:]:
        REFERENCE.write_text(text, encoding="utf-8")
    sys.stdout.write(text)
