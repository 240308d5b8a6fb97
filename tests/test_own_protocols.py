"""The phenomena that are not sweeps, end to end at a tiny size: the moving rubber hand and reaching after the
illusion, each written whole (its table, run.json and, for the moving hand, its figure) with the session's
--quick conv decoder."""
import csv
import json

import pytest

from rhi.master.commands.cli import main


def tiny(path, table: str, protocol: str, checkpoint: str) -> str:
    path.write_text(f"[{table}]\n{protocol}\n[experiment]\ndecoders = [\"conv\"]\nresolution = 32\nsteps = 150\n"
                    f"trials = 1\n[train]\npreset = \"tiny\"\n[decoder]\nconv_checkpoint = \"{checkpoint}\"\n")
    return str(path)


@pytest.mark.parametrize("name, table, protocol, written", [
    ("moving-hand", "moving_hand", "delays = [0.0, 0.4]\nperiod = 2.0", ["moving_hand.csv", "moving_hand.png"]),
    ("reach-after", "reach_after", "release = 1.0\nwindow = 1.0", ["reach_after.csv"]),
])
def test_the_protocol_writes_its_table_whole(name, table, protocol, written, quick_cache, tmp_path, monkeypatch):
    monkeypatch.setenv("RHI_CACHE", str(quick_cache))
    checkpoint = next(quick_cache.glob("conv-*.pt"))
    config = tiny(tmp_path / "p.toml", table, protocol, checkpoint)
    assert main(["phenomenon", name, "--config", config, "--out", str(tmp_path / "out")]) == 0
    out = tmp_path / "out"
    assert {p.name for p in out.iterdir()} >= {*written, "run.json"}
    rows = list(csv.DictReader(open(out / written[0])))
    assert rows and all(row["decoder"] == "conv" for row in rows)
    run = json.loads((out / "run.json").read_text())
    assert run["command"] == f"rhi phenomenon {name}" and run["configuration"]["experiment"]["decoders"] == ["conv"]
