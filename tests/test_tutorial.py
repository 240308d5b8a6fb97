"""examples/tutorial.ipynb runs, at the tiny size (RHI_TUTORIAL_SIZE=tiny), in a kernel of this Python (nbclient):
its quick experiment gives the illusion's drift signs, the FMU body reproduces the native plant, and the engine
stepped by hand gives the experiment's drift."""
import re
from pathlib import Path

import nbformat
from nbclient import NotebookClient

NOTEBOOK = Path(__file__).resolve().parents[1] / "examples" / "tutorial.ipynb"


def printed(notebook) -> str:
    """Everything the notebook's cells printed, in order."""
    return "".join(output.get("text", "") for cell in notebook.cells if cell.cell_type == "code"
                   for output in cell.outputs if output.output_type == "stream" and output.name == "stdout")


def test_the_tutorial_runs_and_its_numbers_hold(tmp_path, monkeypatch):
    monkeypatch.setenv("RHI_TUTORIAL_SIZE", "tiny")
    monkeypatch.setenv("RHI_CACHE", str(tmp_path / "cache"))  # the kernel inherits this environment
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    NotebookClient(notebook, timeout=300, kernel_name="python3",
                   resources={"metadata": {"path": str(tmp_path)}}).execute()  # raises on a failing cell
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
