"""Hostile output folders and the files in them: a manifest entry that leads through a link out of DIR, trial
records and JSON that are not what rhi writes, a FIFO where a file belongs, and a user's file where --out names one.

Each case runs the real command line (tests.faults.rhi: in this process, or a subprocess where noted; cwd the case's
own ``work``, TMPDIR and RHI_CACHE inside its tree) and checks what rhi guarantees (docs/configuration.md, "What rhi
refuses, and what it guarantees"; docs/safety.md): one line on stderr and exit status 2 for a refusal, no traceback,
and nothing changed that rhi did not write. The folders are made in-process as rhi writes them (the units that
write them), so that no case trains a decoder or runs a long sweep first.
"""
from __future__ import annotations

import hashlib
import json
import os
import zipfile
from pathlib import Path

import pytest

from tests.faults import refused, rhi, tiny_checkpoint

VICTIM = b"a file of the user's, outside the output folder\n"


def outside_files(root: Path) -> Path:
    """root/outside: a file of the user's and an empty folder of theirs, which a link in DIR will lead to."""
    outside = root / "outside"
    (outside / "empty").mkdir(parents=True)
    (outside / "victim.txt").write_bytes(VICTIM)
    return outside


def plant_link(folder: Path, outside: Path) -> None:
    """``folder/lnk`` -> ``outside``, and the folder's manifest listing ``lnk/victim.txt`` with that file's true
    size and sha256 and ``lnk/empty`` as one of its folders: the bytes proven, the path not rhi's."""
    (folder / "lnk").symlink_to(outside, target_is_directory=True)
    path = folder / ".rhi-manifest.json"
    manifest = json.loads(path.read_text())
    manifest["files"]["lnk/victim.txt"] = {"bytes": len(VICTIM), "sha256": hashlib.sha256(VICTIM).hexdigest()}
    manifest["folders"] += ["lnk", "lnk/empty"]
    path.write_text(json.dumps(manifest))


def tree(root: Path) -> dict:
    """Every entry under ``root`` by os.lstat, relative name -> what it is: a file's size and sha256, a link's
    target, a folder, or another kind (a FIFO, never opened); and every entry of the folders a link under
    ``root`` leads to, under the link's own name: what is there, whichever way it is reached."""
    import stat

    found = {}
    for folder, names, files in os.walk(root):
        for name in names + files:
            path = Path(folder) / name
            key, mode = path.relative_to(root).as_posix(), os.lstat(path).st_mode
            if stat.S_ISLNK(mode):
                found[key] = ("link", os.readlink(path))
                if path.is_dir():
                    found.update({f"{key}/{inner}": value for inner, value in tree(path).items()})
            elif stat.S_ISDIR(mode):
                found[key] = ("folder",)
            elif stat.S_ISREG(mode):
                found[key] = ("file", hashlib.sha256(path.read_bytes()).hexdigest())
            else:
                found[key] = ("other", stat.S_IFMT(mode))
    return found


def changed_outside(before: dict, after: dict, inside: str) -> list[str]:
    """The entries that changed, but those under ``inside`` (DIR) and the run's own TMPDIR and RHI_CACHE."""
    return sorted(name for name in set(before) | set(after) if before.get(name) != after.get(name)
                  and not name.startswith((inside + "/", "tmp/", "cache/")) and name not in (inside, "tmp", "cache"))


def prepared(root: Path) -> Path:
    """root/work, root/tmp and root/cache, as tests.faults.rhi makes them (made first: they are not the run's)."""
    for name in ("work", "tmp", "cache"):
        (root / name).mkdir(parents=True, exist_ok=True)
    return root / "work"


# ======================================================================================================
# 1-2. A manifest entry is rhi's only at a path inside DIR reached through no link
# ======================================================================================================
def test_sweep_force_never_removes_a_listed_file_reached_through_a_link(tmp_path):
    from rhi.master.sweeps import plan as sweeps
    from rhi.master.sweeps.folder import sweep_folder
    from tests.sweep_files import sweep_file

    work, outside = prepared(tmp_path), outside_files(tmp_path)
    for name, left in (("first", -0.1), ("second", -0.2)):
        sweep_file(work / f"{name}.toml", grid={"conditions.left": [left]}, trials=1, conditions=("left",), workers=1)
    with sweep_folder(work / "out", sweeps.load(work / "first.toml"), False):
        pass  # an earlier sweep's DIR, as rhi sweep writes it: sweep.json and the manifest listing it
    plant_link(work / "out", outside)
    before = tree(tmp_path)
    done = rhi(tmp_path, "sweep", "--config", "second.toml", "--out", "out", "--force")
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert (outside / "victim.txt").read_bytes() == VICTIM and (outside / "empty").is_dir()
    after = tree(tmp_path)
    assert changed_outside(before, after, "work/out") == []
    assert after["work/out/lnk"] == ("link", str(outside))  # the link itself is the user's: it stays
    listed = json.loads((work / "out" / ".rhi-manifest.json").read_text())
    assert not [name for name in [*listed["files"], *listed["folders"]] if name.startswith("lnk")]


FIT = """
[experiment]
steps = 3
resolution = 16
[decoder]
fast = false
conv_checkpoint = "{checkpoint}"
[fit]
quick = true
simulations = 10
calibration = 0
seed = 3
participants_per_batch = 10
workers = 1
posterior_samples = 10
predictive_draws = 1
predictive_participants = 1
[fit.estimator]
hidden_features = 8
transforms = 1
max_epochs = 2
batch_size = 10
threads = 1
[fit.parameters."decoder.visual_variance"]
prior = "log-uniform"
low = 5.0
high = 80.0
"""
DATA = "participant,condition,stimulation,drift_cm\np1,left,sync,-0.3\n"


def fit_folder(work: Path) -> Path:
    """work/out as an interrupted `rhi fit` left it: fit.json, every simulated participant's record (made up
    here: the fit only reads them back), and predictive/ an earlier posterior predictive sweep (another
    fingerprint, as after a change of the data), each with the manifest rhi sweep keeps."""
    from rhi.master.fit.data import read_data
    from rhi.master.fit.plan import draw_participants, read_plan
    from rhi.master.fit.run import fingerprint, prepare_folder
    from rhi.master.fit.simulate import participants_sweep
    from rhi.master.sweeps.folder import sweep_folder

    from rhi.components.body.kinematics import REST_POSE
    from rhi.master.decoders.training_data import HALF_RANGES

    checkpoint = tiny_checkpoint(work / "tiny.pt", rest_pose=list(REST_POSE), half_ranges=list(HALF_RANGES))
    (work / "fit.toml").write_text(FIT.format(checkpoint=checkpoint))
    (work / "data.csv").write_text(DATA)
    plan = read_plan(work / "fit.toml", read_data(work / "data.csv"))
    drawn = draw_participants(plan.parameters, plan.settings)
    prior = participants_sweep(plan, drawn, "prior")
    out = work / "out"
    prepare_folder(out, fingerprint(plan, prior.fingerprint))
    with sweep_folder(out / "simulations", prior, False) as (_, manifest):
        for number, trial in enumerate(prior.trials):
            record = {"id": trial.id, "point": trial.point, "status": "ok",
                      "outcome": {"drift_cm": -0.01 * number, "force_n": 0.0, "gamma_final": 0.1}}
            (out / "simulations" / "trials" / f"{trial.id}.json").write_text(json.dumps(record))
            manifest.add(f"trials/{trial.id}.json")
        manifest.save()
    with sweep_folder(out / "predictive", participants_sweep(plan, drawn[:2], "predictive"), False):
        pass
    return out


def test_fit_never_removes_a_listed_file_of_its_predictive_folder_reached_through_a_link(tmp_path):
    work, outside = prepared(tmp_path), outside_files(tmp_path)
    out = fit_folder(work)
    plant_link(out / "predictive", outside)
    before = tree(tmp_path)
    done = rhi(tmp_path, "fit", "--data", "data.csv", "--config", "fit.toml", "--out", "out", timeout=120)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert "10 run now" not in done.stdout and "0 run now" in done.stdout  # the made-up records were used
    assert (outside / "victim.txt").read_bytes() == VICTIM and (outside / "empty").is_dir()
    after = tree(tmp_path)
    assert changed_outside(before, after, "work/out") == []
    assert after["work/out/predictive/lnk"] == ("link", str(outside))


# ======================================================================================================
# 3. --out FILE never replaces a file rhi did not write; an existing one needs --force
# ======================================================================================================
MINE = b"my own notes, in a file I happened to name like an output\n"


@pytest.fixture(scope="module")
def one_body_ssp(tmp_path_factory) -> Path:
    """A fair SSP package of the kinematic body alone (5 steps), for run-system."""
    from rhi.master.export.body import build_fmu
    from tests.test_hostile_files import one_body_package

    folder = tmp_path_factory.mktemp("ssp")
    return one_body_package(build_fmu(folder / "Body.fmu", "kinematic"), folder / "X.ssp")


def out_file_commands(ssp: Path) -> dict:
    """Each command that writes --out FILE, its suffix, and its arguments but --out: the cheapest run of each."""
    return {"export-body": (".fmu", ["export-body", "--variant", "kinematic"]),
            "export-agent": (".fmu", ["export-agent", "--decoder", "conv", "--checkpoint", "ckpt.pt", "--config",
                                      "c.toml"]),
            "export-system": (".ssp", ["export-system", "--decoder", "conv", "--checkpoint", "ckpt.pt", "--config",
                                       "c.toml", "--body-variant", "kinematic"]),
            "run-system": (".csv", ["run-system", str(ssp)])}


def agent_inputs(work: Path) -> None:
    """A 16 px tiny conv checkpoint and a configuration at 16 px with 2 steps, for the agent's exports."""
    from rhi.components.body.kinematics import REST_POSE
    from rhi.master.decoders.training_data import HALF_RANGES

    tiny_checkpoint(work / "ckpt.pt", rest_pose=list(REST_POSE), half_ranges=list(HALF_RANGES))
    (work / "c.toml").write_text('[experiment]\ndecoders = ["conv"]\nresolution = 16\nsteps = 2\n'
                                 '[decoder]\nfast = false\n')


@pytest.mark.parametrize("command", ["export-body", "export-agent", "export-system", "run-system"])
def test_out_file_never_replaces_a_user_s_file(tmp_path, one_body_ssp, command):
    """Without --force an existing FILE is refused, naming it and --force; with --force, a file that is not one
    rhi wrote of that kind is refused all the same; both leave it, and everything else, as it was."""
    work = prepared(tmp_path)
    agent_inputs(work)
    suffix, arguments = out_file_commands(one_body_ssp)[command]
    (work / f"mine{suffix}").write_bytes(MINE)
    before = tree(tmp_path)
    refused(rhi(tmp_path, *arguments, "--out", f"mine{suffix}"), f"--out mine{suffix} exists; use --force")
    refused(rhi(tmp_path, *arguments, "--out", f"mine{suffix}", "--force"),
            f"mine{suffix} exists and rhi did not write it")
    assert (work / f"mine{suffix}").read_bytes() == MINE
    assert changed_outside(before, tree(tmp_path), "\0") == []


@pytest.mark.parametrize("command", ["export-body", "export-agent", "export-system", "run-system"])
def test_out_file_with_force_replaces_a_file_rhi_wrote_of_its_kind(tmp_path, one_body_ssp, command):
    work = prepared(tmp_path)
    agent_inputs(work)
    suffix, arguments = out_file_commands(one_body_ssp)[command]
    child = command == "run-system"  # its run starts the master's child process: in a process of its own
    done = rhi(tmp_path, *arguments, "--out", f"ours{suffix}", timeout=120, own_process=child)
    assert done.returncode == 0, done.stderr[-2000:]
    first = (work / f"ours{suffix}").read_bytes()
    refused(rhi(tmp_path, *arguments, "--out", f"ours{suffix}"), "--force")
    assert (work / f"ours{suffix}").read_bytes() == first
    done = rhi(tmp_path, *arguments, "--out", f"ours{suffix}", "--force", timeout=120, own_process=child)
    assert done.returncode == 0, done.stderr[-2000:]
    assert sorted(p.name for p in work.iterdir()) == ["c.toml", "ckpt.pt", f"ours{suffix}"]  # nothing left beside it
    if suffix == ".csv":
        assert (work / f"ours{suffix}").read_bytes() == first  # the same run, the same table
    else:
        assert zipfile.ZipFile(work / f"ours{suffix}").testzip() is None


# ======================================================================================================
# 4. A FIFO or a device where a file belongs is refused by its kind, before it is opened
# ======================================================================================================
@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_fit_data_that_is_a_fifo_or_a_device_is_refused_at_once(tmp_path, kind):
    work = prepared(tmp_path)
    (work / "fit.toml").write_text(FIT.format(checkpoint=""))
    data = "/dev/zero" if kind == "device" else "pipe.csv"
    if kind == "fifo":
        os.mkfifo(work / "pipe.csv")  # nothing ever writes it: opening it for reading would wait forever
    before = tree(tmp_path)
    # own process: opening the FIFO would wait forever, reading the device would never end
    refused(rhi(tmp_path, "fit", "--data", data, "--config", "fit.toml", "--out", "out", timeout=30, own_process=True),
            f"data file {data} is not a regular file")
    assert changed_outside(before, tree(tmp_path), "\0") == []


# ======================================================================================================
# 5-6. Trial records and JSON read back from DIR are checked whole: a malformed one is one line, naming it
# ======================================================================================================
DEEP = "[" * 100_000 + "]" * 100_000  # JSON nested 100 000 deep: a RecursionError in json.loads
BAD_RECORDS = {"empty_object": "{}", "array": "[]", "ok_without_outcome": '{"status": "ok"}',
               "failed_without_error": '{"status": "failed"}', "outcome_not_numbers":
               '{"status": "ok", "outcome": {"drift_cm": "far", "force_n": 0, "gamma_final": 0}}',
               "not_json": "{not json", "nested_deep": DEEP}


@pytest.mark.parametrize("name", [*BAD_RECORDS, "fifo"])
def test_a_malformed_trial_record_in_a_sweep_folder_is_refused_naming_it(tmp_path, name):
    from tests.sweep_files import one_trial_sweep_folder

    work = prepared(tmp_path)
    _, record = one_trial_sweep_folder(work)
    if name == "fifo":
        os.mkfifo(record)
    else:
        record.write_text(BAD_RECORDS[name])
    before = tree(tmp_path)
    # the FIFO in its own process: opening it would wait forever
    refused(rhi(tmp_path, "sweep", "--config", "s.toml", "--out", "out", timeout=30, own_process=name == "fifo"),
            f"trial record out/trials/{record.name} is not "
            + ("a regular file" if name == "fifo" else "one rhi wrote"))
    assert changed_outside(before, tree(tmp_path), "\0") == []  # nothing written, in DIR either


@pytest.mark.parametrize("name", ["ok_without_outcome", "nested_deep"])
def test_a_malformed_trial_record_in_a_fit_folder_is_refused_naming_it(tmp_path, name):
    work = prepared(tmp_path)
    out = fit_folder(work)
    record = sorted((out / "simulations" / "trials").glob("*.json"))[3]
    record.write_text(BAD_RECORDS[name])
    before = tree(tmp_path)
    refused(rhi(tmp_path, "fit", "--data", "data.csv", "--config", "fit.toml", "--out", "out"),
            f"trial record out/simulations/trials/{record.name} is not one rhi wrote")
    assert changed_outside(before, tree(tmp_path), "\0") == []


def test_a_fit_json_nested_deep_is_refused_in_one_line(tmp_path):
    work = prepared(tmp_path)
    out = fit_folder(work)
    (out / "fit.json").write_text(DEEP)
    before = tree(tmp_path)
    refused(rhi(tmp_path, "fit", "--data", "data.csv", "--config", "fit.toml", "--out", "out"), "holds no fit")
    assert changed_outside(before, tree(tmp_path), "\0") == []


@pytest.mark.parametrize("command", ["experiment", "sweep"])
def test_an_output_folder_s_own_json_nested_deep_is_refused_in_one_line(tmp_path, command):
    """An experiment's .rhi-manifest.json and a sweep's sweep.json (these two were refused in one line already)."""
    from tests.sweep_files import sweep_file

    work = prepared(tmp_path)
    (work / "out").mkdir()
    if command == "experiment":
        (work / "out" / ".rhi-manifest.json").write_text(DEEP)
        arguments, says = ["experiment", "--quick", "--out", "out", "--force"], "is not an earlier rhi experiment output"
    else:
        (work / "out" / "sweep.json").write_text(DEEP)
        sweep_file(work / "s.toml", trials=1, conditions=("left",), workers=1)
        arguments, says = ["sweep", "--config", "s.toml", "--out", "out"], "holds a sweep.json that rhi sweep did not"
    before = tree(tmp_path)
    refused(rhi(tmp_path, *arguments), says)
    assert changed_outside(before, tree(tmp_path), "\0") == []


# ======================================================================================================
# 7. A fit's refusal advises what rhi fit can do: it has no --force
# ======================================================================================================
@pytest.mark.parametrize("folder, damage", [("simulations", "no_sweep_json"), ("simulations", "another_sweep"),
                                            ("predictive", "no_sweep_json")])
def test_a_fit_folder_whose_sweep_is_not_its_own_is_refused_without_advising_force(tmp_path, folder, damage):
    work = prepared(tmp_path)
    out = fit_folder(work)
    sweep_json = out / folder / "sweep.json"
    if damage == "no_sweep_json":
        sweep_json.unlink()
    else:  # rhi's file, for another sweep than this fit's
        fingerprint = json.loads(sweep_json.read_text())["fingerprint"]
        sweep_json.write_text(sweep_json.read_text().replace(fingerprint, "0" * len(fingerprint)))
    before = tree(tmp_path)
    done = rhi(tmp_path, "fit", "--data", "data.csv", "--config", "fit.toml", "--out", "out")
    refused(done, f"out/{folder}")
    assert "--force" not in done.stderr and "choose another --out" in done.stderr
    assert changed_outside(before, tree(tmp_path), "\0") == []


# ======================================================================================================
# 8. A huge value echoed in an error is cut: the one line stays a line
# ======================================================================================================
@pytest.mark.parametrize("where", ["scheme", "condition_with_spaces", "usage"])
def test_a_huge_value_in_an_error_is_cut_to_a_short_line(tmp_path, where):
    work = prepared(tmp_path)
    texts = {"scheme": '[experiment]\nscheme = "' + "x" * 1_000_000 + '"\n',
             "condition_with_spaces": '[conditions]\nfar = "' + "x " * 500_000 + '"\n[experiment]\nconditions = ["far"]\n'}
    if where == "usage":  # one argument: at most 128 KiB on Linux
        done = rhi(tmp_path, "experiment", "--trials", "9" * 100_000 + "x", "--out", "o")
        says = "invalid int value"
    else:
        (work / "c.toml").write_text(texts[where])
        done = rhi(tmp_path, "experiment", "--quick", "--config", "c.toml", "--out", "o")
        says = {"scheme": "experiment.scheme = 'xxxx", "condition_with_spaces": "conditions.far = 'x x x"}[where]
    refused(done, says)
    assert len(done.stderr) < 2500, len(done.stderr)
    assert "..." in done.stderr and done.stderr.startswith("rhi experiment: error: ")
