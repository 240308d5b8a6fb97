"""rhi deletes only what it wrote: another tool's sweep.json, a user's files where a sweep or an experiment
writes, links out of the output folder, and files that are not checkpoints, each left alone."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from tests.faults import snapshot, tiny_checkpoint


def sweep_of(tmp_path: Path, name: str, grid: dict):
    from rhi.master.sweeps import plan as sweeps
    from tests.sweep_files import sweep_file

    return sweeps.load(sweep_file(tmp_path / f"{name}.toml", grid=grid))


def prepare(out: Path, sweep, force: bool = False) -> None:
    from rhi.master.sweeps.folder import sweep_folder

    with sweep_folder(out, sweep, force):
        pass


def user_files(out: Path) -> dict:
    """A user's own files in the places a sweep writes, and another tool's sweep.json."""
    files = {"sweep.json": '{"study": "optuna", "trials": 3}\n', "figures/loss.png": "png", "trials/0.json": "{}",
             "summary.csv": "a,b\n1,2\n", "notes.txt": "mine"}
    for name, text in files.items():
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_text(text)
    return snapshot(out)


@pytest.mark.parametrize("force", [False, True])
def test_a_sweep_json_of_another_tool_is_never_replaced(tmp_path, force):
    from rhi.master.cosim import ConfigError

    out = tmp_path / "out"
    before = user_files(out)
    with pytest.raises(ConfigError, match="holds a sweep.json that rhi sweep did not write"):
        prepare(out, sweep_of(tmp_path, "s", {"conditions.left": [-0.1, -0.2]}), force)
    assert snapshot(out) == before


@pytest.mark.parametrize("content", ['[1, 2]', '"text"', '{"fingerprint": 3}', "{not json"])
def test_a_sweep_json_that_is_not_rhi_s_object_is_refused_in_one_line(tmp_path, content):
    from rhi.master.cosim import ConfigError

    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "sweep.json").write_text(content)
    with pytest.raises(ConfigError, match="did not write"):
        prepare(tmp_path / "out", sweep_of(tmp_path, "s", {"conditions.left": [-0.1]}), True)


def test_force_removes_only_the_older_sweep_s_own_files(tmp_path):
    """Only what the older sweep's manifest lists, unchanged since: a file of yours, or one you edited, stays;
    one the new sweep would write over is refused, naming it, before anything is removed."""
    from rhi.master.cosim import ConfigError
    from rhi.master.sweeps.folder import sweep_folder

    out = tmp_path / "out"
    first = sweep_of(tmp_path, "first", {"conditions.left": [-0.1, -0.2]})
    with sweep_folder(out, first, False) as (_, manifest):  # as rhi sweep writes: each file, then it is listed
        (out / "figures").mkdir()
        written = [f"trials/{trial.id}.json" for trial in first.trials[:2]]
        for name in written + ["figures/conditions.left.png", "index.csv", "summary.csv"]:
            (out / name).write_text(json.dumps({"id": Path(name).stem}) if name.startswith("trials") else "rhi's")
            manifest.add(name)
        manifest.save()
    edited = out / written[1]
    edited.write_text(edited.read_text() + "\n")  # edited since: not rhi's any more
    mine = {"figures/loss.png": "mine", "trials/notes.json": '{"id": "notes"}', "trials/x.json": "{}"}
    for name, text in mine.items():
        (out / name).write_text(text)
    second = sweep_of(tmp_path, "second", {"conditions.right": [0.1, 0.2]})
    (out / "summary.csv").write_text("my own summary")  # edited, and the new sweep writes summary.csv
    before = snapshot(out)
    with pytest.raises(ConfigError, match=r"summary.csv would be written over but is not what rhi sweep wrote there"):
        prepare(out, second, force=True)
    assert snapshot(out) == before  # refused before anything was removed
    (out / "summary.csv").unlink()
    prepare(out, second, force=True)
    assert all((out / name).read_text() == text for name, text in mine.items()) and edited.exists()
    assert not (out / written[0]).exists() and not (out / "figures" / "conditions.left.png").exists()
    assert not (out / "index.csv").exists() and json.loads((out / "sweep.json").read_text())["command"] == "rhi sweep"
    listed = json.loads((out / ".rhi-manifest.json").read_text())["files"]
    assert sorted(listed) == ["sweep.json"]  # the new sweep's, as written so far


@pytest.mark.parametrize("link", ["figures", "trials", "summary.csv"])
def test_a_link_where_a_sweep_writes_is_refused_and_what_it_leads_to_is_untouched(tmp_path, link):
    from rhi.master.cosim import ConfigError

    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    first = sweep_of(tmp_path, "first", {"conditions.left": [-0.1, -0.2]})
    prepare(out, first)
    elsewhere.mkdir()
    (elsewhere / "conditions.left.png").write_text("not rhi's")
    if (out / link).exists():
        (out / link).rmdir()
    (out / link).symlink_to(elsewhere if link != "summary.csv" else elsewhere / "conditions.left.png")
    with pytest.raises(ConfigError, match="is a symbolic link"):
        prepare(out, sweep_of(tmp_path, "second", {"conditions.right": [0.1]}), force=True)
    assert (elsewhere / "conditions.left.png").read_text() == "not rhi's"


def test_experiment_force_never_removes_a_folder_where_an_output_file_belongs(tmp_path):
    from rhi.master.cosim import ConfigError
    from rhi.master.outputs.files import check_output
    from rhi.master.outputs.manifest import Manifest

    out = tmp_path / "out"
    (out / "trials.csv").mkdir(parents=True)
    (out / "trials.csv" / "mine.txt").write_text("mine")
    (out / "run.json").write_text('{"command": "rhi experiment", "figures": []}')
    manifest = Manifest(out, "rhi experiment", folders={"trials.csv"})  # even a manifest naming the folder
    manifest.add("run.json")
    manifest.save()
    with pytest.raises(ConfigError, match=r"not an earlier rhi experiment output \(it holds trials.csv/mine.txt\)"):
        check_output(out, force=True)
    assert (out / "trials.csv" / "mine.txt").read_text() == "mine"


def test_train_never_replaces_a_file_that_is_not_a_checkpoint(tmp_path):
    from rhi.master.cosim import ConfigError
    from rhi.master.decoders.training import check_target

    (tmp_path / "notes.txt").write_text("mine")
    (tmp_path / "notes.pt").write_text("mine")
    with pytest.raises(ConfigError, match="must be a file name ending in .pt"):
        check_target(tmp_path / "notes.txt")
    with pytest.raises(ConfigError, match="exists and is not a decoder checkpoint"):
        check_target(tmp_path / "notes.pt")
    assert check_target(tiny_checkpoint(tmp_path / "old.pt")) == tmp_path / "old.pt"  # ours: replaced
    assert (tmp_path / "notes.txt").read_text() == (tmp_path / "notes.pt").read_text() == "mine"


@pytest.mark.parametrize("earlier", [False, True])
def test_an_output_folder_that_is_a_mount_point_is_written_in_place(tmp_path, monkeypatch, earlier):
    """A mount point cannot be renamed onto (EBUSY, as the kernel answers): staging goes inside it."""
    import errno

    from rhi.master.outputs import files

    out = tmp_path / "volume"
    out.mkdir()
    if earlier:  # an earlier output of ours, replaced with --force
        from rhi.master.outputs.manifest import Manifest

        (out / "run.json").write_text('{"command": "rhi experiment", "figures": []}')
        (out / "summary.csv").write_text("old")
        Manifest.of(out, "rhi experiment").save()
    real_replace, real_ismount = os.replace, os.path.ismount

    def replace(source, target):
        if Path(target).absolute() == out.absolute():
            raise OSError(errno.EBUSY, "Device or resource busy", str(target))
        return real_replace(source, target)

    monkeypatch.setattr(os, "replace", replace)
    monkeypatch.setattr(os.path, "ismount", lambda path: Path(path).absolute() == out.absolute() or real_ismount(path))
    with files.output_folder(out, force=earlier) as staging:
        assert staging.parent == out  # on the volume's own file system
        (staging / "summary.csv").write_text("new")
        (staging / "run.json").write_text('{"command": "rhi experiment", "figures": []}')
    assert sorted(p.name for p in out.iterdir()) == [".rhi-manifest.json", "run.json", "summary.csv"]
    assert (out / "summary.csv").read_text() == "new"
    assert not list(tmp_path.glob(".volume.*"))  # nothing left beside it
