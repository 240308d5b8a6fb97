"""examples/tutorial.ipynb's stored outputs: made by one command, checked by the suite against a fresh run.

``python -m tests.notebook`` (``make tutorial``) runs the notebook at its full size in a kernel of this Python and
stores it with its outputs, recording in its metadata (``rhi``) the digest of the code cells that made them, the
wall time, the CPU and the versions. ``tests/test_tutorial.py`` runs it again at the tiny size and compares: the
stored outputs come from the cells as they are now (the digest), and every cell prints the same lines with the
numbers left out (:func:`printed_shape`).
"""
from __future__ import annotations

import hashlib
import os
import re
import sys
import tempfile
import time
from pathlib import Path

import nbformat
from nbclient import NotebookClient

NOTEBOOK = Path(__file__).resolve().parents[1] / "examples" / "tutorial.ipynb"
NUMBER = re.compile(r"[+-]?\d+(\.\d+)?(e[+-]?\d+)?")


def sources_digest(notebook) -> str:
    """sha256 of the code cells' sources, in order: which cells made the stored outputs."""
    text = "\n\x00".join(cell.source for cell in notebook.cells if cell.cell_type == "code")
    return hashlib.sha256(text.encode()).hexdigest()


def printed(notebook) -> str:
    """Everything the notebook's cells printed, in order."""
    return "".join(output.get("text", "") for cell in notebook.cells if cell.cell_type == "code"
                   for output in cell.outputs if output.output_type == "stream" and output.name == "stdout")


def printed_shape(notebook) -> list[list[str]]:
    """Per code cell, its printed lines with each number replaced by ``#``, and ``<kind>`` for each rich output
    (a figure, a table): what a run of any size shows, whatever its numbers."""
    shapes = []
    for cell in (cell for cell in notebook.cells if cell.cell_type == "code"):
        lines = []
        for output in cell.outputs:
            if output.output_type == "stream" and output.name == "stdout":
                lines += [NUMBER.sub("#", line) for line in output.text.splitlines()]
            elif output.output_type in ("display_data", "execute_result"):
                lines.append("<" + ",".join(sorted(output.data)) + ">")
        shapes.append(lines)
    return shapes


def execute(notebook, folder: Path, tiny: bool, timeout: int = 900) -> None:
    """Run ``notebook`` in place in a python3 kernel whose working folder is ``folder``: at the tiny size or the
    full one. The kernel inherits this process's environment."""
    saved = os.environ.get("RHI_TUTORIAL_SIZE")
    os.environ["RHI_TUTORIAL_SIZE"] = "tiny" if tiny else "full"
    try:
        NotebookClient(notebook, timeout=timeout, kernel_name="python3",
                       resources={"metadata": {"path": str(folder)}}).execute()  # raises on a failing cell
    finally:
        if saved is None:
            os.environ.pop("RHI_TUTORIAL_SIZE")
        else:
            os.environ["RHI_TUTORIAL_SIZE"] = saved


def main() -> int:
    """Run the notebook at its full size and store it with its outputs and their provenance, whole or not at all."""
    from rhi.master.outputs.atomic import atomic_write
    from rhi.master.outputs.provenance import package_versions

    notebook = nbformat.read(NOTEBOOK, as_version=4)
    started, cpu_started = time.perf_counter(), os.times()
    with tempfile.TemporaryDirectory(prefix="rhi_tutorial_") as folder:
        execute(notebook, Path(folder), tiny=False)
    ended = os.times()
    notebook.metadata["rhi"] = {
        "sources_sha256": sources_digest(notebook),
        "wall_s": round(time.perf_counter() - started, 1),
        # the kernel is a child of this process: its CPU time counts once it has exited
        "cpu_s": round(sum(ended[:4]) - sum(cpu_started[:4]), 1),
        "cores": os.cpu_count(), "versions": package_versions()}
    atomic_write(NOTEBOOK, nbformat.writes(notebook) + "\n")
    print(f"{NOTEBOOK.name}: ran in {notebook.metadata['rhi']['wall_s']} s wall "
          f"({notebook.metadata['rhi']['cpu_s']} CPU-s) on {os.cpu_count()} cores")
    return 0


if __name__ == "__main__":
    sys.exit(main())
