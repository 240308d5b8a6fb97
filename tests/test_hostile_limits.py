"""Hostile limits: a file of the wrong kind where a checkpoint belongs, settings whose size or number implies more
memory or work than any machine has, values that are not numbers where numbers belong, and settings read from one
file but not from another.

Each case runs the real command line (tests.faults.rhi: a subprocess, cwd the case's own ``work``, TMPDIR and
RHI_CACHE inside its tree) where the refusal is the command's, and checks what rhi guarantees
(docs/configuration.md, "What rhi refuses, and what it guarantees"; docs/safety.md): one line on stderr and exit
status 2 for a refusal, before any work, no traceback, nothing written. No case trains a default decoder.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests.faults import refused, rhi
from tests.test_hostile_folders import changed_outside, prepared, tree


# ======================================================================================================
# 4b. A FIFO or a device where a checkpoint belongs is refused by its kind, before it is opened
# ======================================================================================================
def hostile_file(work: Path, kind: str) -> str:
    if kind == "device":
        return "/dev/zero"
    os.mkfifo(work / "pipe.pt")  # nothing ever writes it: opening it for reading would wait forever
    return "pipe.pt"


@pytest.mark.parametrize("kind", ["fifo", "device"])
@pytest.mark.parametrize("command", ["experiment", "bench", "export-agent"])
def test_a_checkpoint_that_is_a_fifo_or_a_device_is_refused_by_its_kind(tmp_path, kind, command):
    work = prepared(tmp_path)
    path = hostile_file(work, kind)
    arguments = {"experiment": ["experiment", "--quick", "--conv-checkpoint", path, "--out", "out"],
                 "bench": ["bench", "--quick", "--checkpoint", path],
                 "export-agent": ["export-agent", "--decoder", "conv", "--checkpoint", path, "--out", "a.fmu"]}[command]
    before = tree(tmp_path)
    says = f"--checkpoint {path}" if command == "bench" else f"decoder.conv_checkpoint: {path}"
    refused(rhi(tmp_path, *arguments, timeout=30), f"{says} is not a regular file (a FIFO, a device or a socket)")
    assert changed_outside(before, tree(tmp_path), "\0") == []


@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_a_checkpoint_loaded_directly_that_is_a_fifo_or_a_device_is_refused_without_opening_it(tmp_path, kind):
    import signal

    from components.vision import checkpoint

    def hung(*_):
        raise TimeoutError("checkpoint.load opened the FIFO and waited for a writer")

    path = hostile_file(tmp_path, kind)
    previous = signal.signal(signal.SIGALRM, hung)
    signal.alarm(10)
    try:
        with pytest.raises(checkpoint.CheckpointError, match="is not a regular file"):
            checkpoint.load(tmp_path / path if kind == "fifo" else path)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


# ======================================================================================================
# 16. A checkpoint whose metadata JSON nests 100 000 deep is refused in one line
# ======================================================================================================
def test_a_checkpoint_whose_metadata_nests_deep_is_refused_in_one_line(tmp_path):
    import torch

    from components.vision.checkpoint import FORMAT
    from tests.test_hostile_folders import DEEP

    work = prepared(tmp_path)
    torch.save({"format": FORMAT, "metadata": DEEP, "weights": {}}, work / "deep.pt")
    before = tree(tmp_path)
    refused(rhi(tmp_path, "experiment", "--quick", "--conv-checkpoint", "deep.pt", "--out", "out", timeout=30),
            "deep.pt: its metadata nests over")
    assert changed_outside(before, tree(tmp_path), "\0") == []
