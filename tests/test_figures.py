"""Figures for notebooks: rhi never switches matplotlib's backend nor opens a pyplot figure; each figure
function returns its Figure, whose drawing is the numbers it is given, and saving it gives pyplot's bytes."""
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

CHILD = """
import importlib, sys
import matplotlib
before = matplotlib.get_backend()
import matplotlib.pyplot as plt
for name in sys.argv[1:]:
    importlib.import_module(name)
import numpy as np
from matplotlib.figure import Figure
from rhi.master.outputs import figures
from rhi.master.tasks.illusion import Trial
trials = [Trial("conv", c, "sync", 0, 0, 0.0, 0.0, 0.1) for c in ("left", "right")]
made = figures.final_bars(trials, np.ones((3, 2)), "drift (cm)")
assert isinstance(made, Figure), type(made)
assert matplotlib.get_backend() == before, (before, matplotlib.get_backend())
assert plt.get_fignums() == [], plt.get_fignums()
print("unchanged", before)
"""


def figure_modules() -> list[str]:
    """Every rhi module whose source uses matplotlib, and those that publish figures through them."""
    found = ["rhi." + ".".join(path.relative_to(ROOT).with_suffix("").parts) for folder in ("master", "components")
             for path in sorted((ROOT / folder).rglob("*.py")) if "matplotlib" in path.read_text()]
    return [name.removesuffix(".__init__") for name in found] + [
        "rhi.master.tasks.illusion.publish", "rhi.master.tasks.reach.publish", "rhi.master.fit.run", "rhi.master.sweeps.run",
        "rhi.master.phenomena.moving_hand", "rhi.master.commands.cli"]


def test_importing_rhi_keeps_the_backend_and_opens_no_pyplot_figure():
    # svg: a backend other than the Agg that the old modules switched to, so a switch shows
    modules = figure_modules()
    assert "rhi.master.outputs.figures" in modules and "rhi.master.fit.report" in modules
    done = subprocess.run([sys.executable, "-c", CHILD, *modules], capture_output=True, text=True, timeout=120,
                          cwd=ROOT, env={**__import__("os").environ, "MPLBACKEND": "svg"})
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip() == "unchanged svg"


def test_a_figure_function_returns_its_figure_drawing_the_means():
    from matplotlib.figure import Figure
    from rhi.master.outputs import figures
    from rhi.master.tasks.illusion import Trial

    trials = [Trial("conv", "left", "sync", i, i, 0.0, 0.0, 0.1) for i in range(2)] + \
             [Trial("conv", "right", "sync", 0, 2, 0.0, 0.0, 0.1)]
    values = np.array([[0.0, 0.0, 0.0], [1.0, 3.0, -2.0]])    # the final row: left 1 and 3, right -2
    made = figures.final_bars(trials, values, "final drift (cm)")
    assert isinstance(made, Figure)
    heights = [bar.get_height() for bar in made.axes[0].patches]
    assert heights == [2.0, -2.0]    # the means by hand, exact in binary
    assert made.axes[0].get_title() == "sync" and made.axes[0].get_ylabel() == "final drift (cm)"


def test_saving_the_figure_gives_the_bytes_pyplot_gave(tmp_path):
    """The object API's PNG equals the one the same drawing made through pyplot (the figures before they returned
    Figures): the published figures' bytes did not change."""
    import matplotlib.pyplot as plt
    from rhi.master.outputs import figures
    from rhi.master.tasks.illusion import Trial

    trials = [Trial("conv", c, s, 0, 0, 0.0, 0.0, 0.1) for c in ("left", "right") for s in ("sync", "async")]
    values = np.array([[0.0] * 4, [1.0, -0.5, 2.0, 0.25]])
    figures.save(figures.final_bars(trials, values, "final drift (cm)"), tmp_path / "object.png")
    old, axes = plt.subplots(1, 2, figsize=(9.0, 3.6), sharey=True, squeeze=False)
    try:
        figures.bars(axes[0], trials, values[-1], "final drift (cm)")
        old.tight_layout()
        old.savefig(tmp_path / "pyplot.png", format="png", dpi=110, metadata=figures.METADATA)
    finally:
        plt.close(old)
    assert (tmp_path / "object.png").read_bytes() == (tmp_path / "pyplot.png").read_bytes()


NOTEBOOK_CELLS = [
    "%matplotlib inline",
    # a tiny experiment with rhi's figure modules loaded, then a figure of the user's own through pyplot
    "import matplotlib.pyplot as plt\n"
    "import rhi\n"
    "from rhi.master.outputs import figures\n"
    "from rhi.master.fit import report\n"
    "from rhi.master.phenomena import report as phenomena_report\n"
    "from rhi.master.sweeps import plots\n"
    "r = rhi.run_experiment(rhi.load_config(experiment__trials=1, experiment__steps=10,\n"
    "    experiment__decoders=['conv'], experiment__conditions=['left'], experiment__stimulations=['sync']))\n"
    "plt.plot(r.per_step['time_s'], r.per_step['drift_cm'].values.T)\n"
    "plt.show()",
    # rhi's own figure, returned: shown as the cell's value, and only then
    "figures.gamma_over_time(r.result.trials, r.result.times, r.result.per_step['gamma'])",
]


def test_a_notebook_shows_its_own_pyplot_figure_and_rhi_s_returned_one(tmp_path, monkeypatch):
    import nbformat
    from nbclient import NotebookClient

    monkeypatch.setenv("RHI_CACHE", str(tmp_path / "cache"))  # the kernel inherits this environment
    notebook = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(source) for source in NOTEBOOK_CELLS])
    NotebookClient(notebook, timeout=300, kernel_name="python3",
                   resources={"metadata": {"path": str(tmp_path)}}).execute()  # raises on a failing cell
    _, own, returned = ([output for output in cell.outputs if "image/png" in output.get("data", {})]
                        for cell in notebook.cells)
    assert [output.output_type for output in own] == ["display_data"]       # plt.show() showed it
    assert [output.output_type for output in returned] == ["execute_result"]  # the Figure, as the cell's value
    assert not [output for output in notebook.cells[1].outputs if output.output_type == "error"]
