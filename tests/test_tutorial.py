"""examples/tutorial.ipynb runs, at the tiny size (RHI_TUTORIAL_SIZE=tiny), in a kernel of this Python (nbclient):
its run in memory gives the illusion's drift signs, both models draw the believed hand toward the rubber hand under
synchronous touch, the fit's estimate lies in its prior's support, the FMU body reproduces the native plant, and
the engine stepped by hand gives the experiment's drift. The notebook ships with the outputs of its full size, made
by `make tutorial` (tests/notebook.py) from the cells as they are, within the ten minutes its title says, and
printing what a fresh run prints."""
import re

import nbformat

import rhi

from tests.notebook import NOTEBOOK, execute, printed, printed_shape, sources_digest


def test_the_tutorial_runs_and_its_numbers_hold(tmp_path, monkeypatch):
    monkeypatch.setenv("RHI_CACHE", str(tmp_path / "cache"))  # the kernel inherits this environment
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    execute(notebook, tmp_path, tiny=True, timeout=300)
    # The stored outputs are this notebook's at its full size: the same lines, the numbers aside.
    assert printed_shape(notebook) == printed_shape(nbformat.read(NOTEBOOK, as_version=4))
    text = printed(notebook)
    assert "failed trials: 0" in text, text
    drift = {(condition, stimulation): float(value) for condition, stimulation, value in
             re.findall(r"^ *(left|center|right) +(sync|async): drift (\S+) cm", text, re.MULTILINE)}
    assert len(drift) == 6, text
    # Synchronous touch draws the believed hand toward the rubber hand: Left negative, Right positive.
    assert drift[("left", "sync")] < 0 < drift[("right", "sync")], drift
    for condition in ("left", "right"):  # asynchronous touch attenuates it
        assert abs(drift[(condition, "async")]) < abs(drift[(condition, "sync")]), drift
    bodies = {body: float(value) for body, value in
              re.findall(r"^(native body|FMU body|by hand): +drift (\S+) cm", text, re.MULTILINE)}
    assert set(bodies) == {"native body", "FMU body", "by hand"}, text
    assert bodies["native body"] < 0  # the trial is Left, synchronous
    # The run's own Left synchronous trial (one per cell, the exact decoder at the tiny size), to its 4 printed decimals.
    assert abs(drift[("left", "sync")] - bodies["native body"]) <= 0.5e-4, (drift, bodies)
    # The FMU wraps the same plant code and the engine by hand runs the same system: equal up to the
    # 12 printed decimals (the drifts agree to 1e-9 cm in tests/test_example.py).
    assert bodies["FMU body"] == bodies["native body"] == bodies["by hand"], bodies
    assert sum(output.output_type == "display_data" for cell in notebook.cells if cell.cell_type == "code"
               for output in cell.outputs) == 2  # the two figures
    models_hold(text)
    median, low, high = map(float, re.search(r"^me: decoder\.visual_variance median (\S+), 90 % interval (\S+) to "
                                             r"(\S+)$", text, re.MULTILINE).groups())
    assert 5.0 <= low <= median <= high <= 80.0  # within the log-uniform prior's support [5, 80]


def models_hold(text: str) -> None:
    """Each model's Left and Right lines: synchronous touch draws the believed hand toward the rubber hand."""
    found = {(model, condition): (float(sync), float(late)) for model, condition, sync, late in re.findall(
        r"^ *(paper|causal|ownership) +(left|right): drift sync (\S+) cm, async (\S+) cm$", text, re.MULTILINE)}
    assert set(found) == {(m, c) for m in ("paper", "causal", "ownership") for c in ("left", "right")}, text
    for model in ("paper", "causal", "ownership"):
        assert found[(model, "left")][0] < 0 < found[(model, "right")][0], found


def test_the_tutorial_ships_with_the_outputs_of_its_full_size():
    """Every code cell of the stored notebook has run (outputs a reader on the web sees), made by `make tutorial`
    from the cells as they are now, in no more than the ten minutes of its title on the machine it names: its
    numbers show the illusion at the paper's 30 s trials, and its two figures are there."""
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    made = notebook.metadata["rhi"]
    assert made["sources_sha256"] == sources_digest(notebook), "cells changed since `make tutorial` stored outputs"
    assert made["wall_s"] <= 600, made  # "in ten minutes"
    code = [cell for cell in notebook.cells if cell.cell_type == "code"]
    assert all(cell.outputs for cell in code[1:]), "a code cell without outputs"  # the first only sets names
    text = printed(notebook)
    assert "failed trials: 0" in text and "after 1500 steps" in text, text
    assert f"models: {', '.join(rhi.models())}\n" in text, text  # every registered model, as the code has them
    models_hold(text)
    assert sum(output.output_type == "display_data" for cell in code for output in cell.outputs) == 2
