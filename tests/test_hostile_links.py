"""Links at rhi's own names, and ownership by what this process made: a link named ``.lock`` in a sweep's or a
fit's folder, ``.DIR.lock`` beside DIR, a link at every lock, marker, manifest and staging name rhi uses, and a
refused run beside another that is writing the same folder (docs/safety.md).

What each case checks: the file a link leads to keeps its bytes, a dangling link's target is never created,
the link itself stays, and a folder another run made is never removed by the run that was refused.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from rhi.master.cosim import ConfigError
from tests.faults import snapshot

VICTIM = b"a file of the user's, outside the output folder\n"


def sweep_of(tmp_path: Path, grid: dict | None = None):
    from rhi.master.sweeps import plan as sweeps
    from tests.sweep_files import sweep_file

    return sweeps.load(sweep_file(tmp_path / "s.toml", grid=grid or {"conditions.left": [-0.1]}))


def prepare(out: Path, sweep, force: bool = False) -> None:
    from rhi.master.sweeps.folder import sweep_folder

    with sweep_folder(out, sweep, force):
        pass


def victims(root: Path) -> tuple[Path, Path]:
    """root/outside/victim.txt (a file of the user's) and root/outside/ghost.txt (absent: a dangling link's)."""
    (root / "outside").mkdir(exist_ok=True)
    (root / "outside" / "victim.txt").write_bytes(VICTIM)
    return root / "outside" / "victim.txt", root / "outside" / "ghost.txt"


def untouched(victim: Path, ghost: Path) -> None:
    assert victim.read_bytes() == VICTIM  # not truncated, not written
    assert not ghost.exists() and not ghost.is_symlink()  # a dangling link's target never created


# -- a link named .lock inside a sweep's, a fit's or a phenomenon's folder -------------------------------
@pytest.mark.parametrize("inner", ["", "simulations", "predictive", "paper"])
@pytest.mark.parametrize("dangling", [False, True])
def test_a_link_named_lock_in_a_sweep_folder_is_refused_and_never_followed(tmp_path, inner, dangling):
    """A finished sweep's folder (a fit's simulations/ or predictive/, a phenomenon's paper/ are sweep folders too)
    with a link planted at .lock: refused in one line; the file it leads to keeps its bytes, a dangling link's
    target is not made."""
    victim, ghost = victims(tmp_path)
    out = tmp_path / "out" / inner
    out.parent.mkdir(exist_ok=True)
    sweep = sweep_of(tmp_path)
    prepare(out, sweep)  # a sweep's folder as rhi leaves it
    (out / ".lock").unlink(missing_ok=True)
    (out / ".lock").symlink_to(ghost if dangling else victim)
    with pytest.raises(ConfigError, match=r"\.lock is a symbolic link"):
        prepare(out, sweep)
    untouched(victim, ghost)
    assert (out / ".lock").is_symlink()


def test_a_finished_sweep_leaves_no_lock_and_a_killed_one_s_is_taken_over(tmp_path):
    """The lock this sweep made goes when it ends; an empty .lock a killed run left is locked, replaced by one of
    this run's own, and removed at the end; a .lock with content (not rhi's) is refused and kept."""
    out, sweep = tmp_path / "out", sweep_of(tmp_path)
    prepare(out, sweep)
    assert not (out / ".lock").exists()
    (out / ".lock").touch()  # what a SIGKILL leaves
    prepare(out, sweep)
    assert not (out / ".lock").exists()
    (out / ".lock").write_text("mine")
    with pytest.raises(ConfigError, match="is not rhi's lock file"):
        prepare(out, sweep)
    assert (out / ".lock").read_text() == "mine"


# -- .DIR.lock beside DIR ------------------------------------------------------------------------------
@pytest.mark.parametrize("planted", ["dangling link", "link to a file", "file of the user's"])
def test_the_lock_beside_dir_never_follows_a_link_nor_removes_what_it_did_not_make(tmp_path, planted):
    from rhi.master.outputs.files import output_folder

    victim, ghost = victims(tmp_path)
    lock = tmp_path / ".out.lock"
    if planted == "file of the user's":
        lock.write_bytes(VICTIM)
    else:
        lock.symlink_to(ghost if planted == "dangling link" else victim)
    before = os.readlink(lock) if lock.is_symlink() else lock.read_bytes()
    with pytest.raises(ConfigError, match=r"\.out\.lock (is a symbolic link|exists and is not rhi's lock file)"):
        with output_folder(tmp_path / "out", force=False):
            pytest.fail("the run must not start")
    untouched(victim, ghost)
    assert (os.readlink(lock) if lock.is_symlink() else lock.read_bytes()) == before  # still there, as it was
    assert not (tmp_path / "out").exists()


def test_the_lock_beside_dir_is_removed_only_while_it_is_the_one_this_run_made(tmp_path):
    """A user's file put in place of the lock while the run goes on (the lock's name taken over) stays."""
    from rhi.master.outputs.files import output_folder

    lock = tmp_path / ".out.lock"
    with output_folder(tmp_path / "out", force=False) as staging:
        (staging / "a.txt").write_text("result")
        assert lock.is_file()
        lock.unlink()
        lock.write_bytes(VICTIM)
    assert lock.read_bytes() == VICTIM and (tmp_path / "out" / "a.txt").read_text() == "result"


# -- a refused concurrent run never deletes the other's folder --------------------------------------------
def other_run_appears(monkeypatch, out: Path, locks: list[str]):
    """Another run makes ``out`` (and holds the locks ``locks`` under it, a file of its own beside them) just as
    this run is about to make it: the moment the two race for. Returns the other run's held locks."""
    from rhi.master.outputs.own_paths import LockFile

    real, held = os.mkdir, []

    def mkdir(path, *args, **kwargs):
        if Path(path) == out and not held:
            real(path, *args, **kwargs)
            (out / "theirs.txt").write_text("the other run's")
            for name in locks:
                (out / name).parent.mkdir(parents=True, exist_ok=True)
                held.append(LockFile(out / name, "busy").acquire())
        return real(path, *args, **kwargs)

    monkeypatch.setattr(os, "mkdir", mkdir)
    return held


def test_a_refused_sweep_never_removes_a_folder_another_made(tmp_path, monkeypatch):
    out, sweep = tmp_path / "out", sweep_of(tmp_path)
    held = other_run_appears(monkeypatch, out, [".lock"])
    with pytest.raises(ConfigError, match="another rhi sweep is writing"):
        prepare(out, sweep)
    assert (out / "theirs.txt").read_text() == "the other run's"
    for lock in held:
        lock.release()


def test_a_refused_fit_never_removes_the_live_folder_of_another(tmp_path, monkeypatch, capsys):
    """Two `rhi fit --out out` at once: the one refused (the other holds DIR, its simulations under way) leaves
    DIR as the other has it."""
    from rhi.master.commands.cli import main
    from tests.test_fit import DATA, FIT

    (tmp_path / "fit.toml").write_text(FIT.format(steps=5, simulations=20, calibration=0))
    (tmp_path / "data.csv").write_text(DATA)
    out = tmp_path / "out"
    held = other_run_appears(monkeypatch, out, [".lock", "simulations/.lock"])
    status = main(["fit", "--data", str(tmp_path / "data.csv"), "--config", str(tmp_path / "fit.toml"),
                   "--out", str(out)])
    err = capsys.readouterr().err
    assert status == 2 and "is writing to" in err and "Traceback" not in err, err
    assert (out / "theirs.txt").read_text() == "the other run's" and (out / "simulations").is_dir()
    for lock in held:
        lock.release()


# -- every lock, marker, manifest and staging name: a link planted at each -------------------------------------------
def run_refused_or_not(action) -> None:
    try:
        action()
    except ConfigError:
        pass


def walk_cases(tmp_path: Path):
    """(the name, how a link is planted at it, the rhi call that uses the name) for every bookkeeping name rhi
    opens, makes or removes."""
    from rhi.master.fit.run import prepare_folder, reports_manifest, written
    from rhi.master.outputs import files, scratch
    from rhi.master.outputs.files import output_folder
    from rhi.master.outputs.own_paths import LockFile

    sweep = sweep_of(tmp_path)

    def a_sweep(out):
        prepare(out, sweep)
        (out / ".lock").unlink(missing_ok=True)

    def experiment_output(out):
        with output_folder(out, False) as staging:
            (staging / "summary.csv").write_text("a\n1\n")

    def publish_into(out):
        with output_folder(out, True) as staging:
            (staging / "summary.csv").write_text("a\n2\n")

    def staging_folder(parent):
        partial = parent / ".out.abcdefgh.partial"
        partial.mkdir()
        (partial / "result.csv").write_text("x")
        return partial

    return [
        (".DIR.lock", lambda d, t: (d / ".out.lock").symlink_to(t), lambda d: experiment_output(d / "out")),
        ("DIR/.lock of a sweep", lambda d, t: (a_sweep(d / "out"), (d / "out" / ".lock").symlink_to(t)),
         lambda d: prepare(d / "out", sweep)),
        ("DIR/.lock of a fit", lambda d, t: (d / "out").mkdir() or (d / "out" / ".lock").symlink_to(t),
         lambda d: prepare_folder(d / "out", "identity")),
        ("DIR/sweep.json", lambda d, t: (d / "out").mkdir() or (d / "out" / "sweep.json").symlink_to(t),
         lambda d: prepare(d / "out", sweep, True)),
        ("DIR/fit.json", lambda d, t: (d / "out").mkdir() or (d / "out" / "fit.json").symlink_to(t),
         lambda d: prepare_folder(d / "out", "identity")),
        ("DIR/.rhi-manifest.json of a sweep",
         lambda d, t: (a_sweep(d / "out"), (d / "out" / ".rhi-manifest.json").unlink(),
                       (d / "out" / ".rhi-manifest.json").symlink_to(t)),
         lambda d: prepare(d / "out", sweep_of(d, {"conditions.left": [-0.2]}), True)),
        ("DIR/.rhi-manifest.json of an output",
         lambda d, t: (experiment_output(d / "out"), (d / "out" / ".rhi-manifest.json").unlink(),
                       (d / "out" / ".rhi-manifest.json").symlink_to(t)),
         lambda d: publish_into(d / "out")),
        ("DIR/.rhi-manifest.json of a fit",
         lambda d, t: (d / "out").mkdir() or (d / "out" / ".rhi-manifest.json").symlink_to(t),
         lambda d: written(reports_manifest(d / "out"), "run.json")),
        (".DIR.XXXXXXXX.partial (a staging folder)", lambda d, t: (d / ".out.abcdefgh.partial").symlink_to(t.parent),
         lambda d: files.clean_stale(d / "out")),
        (".DIR.XXXXXXXX.old (an output moved aside)", lambda d, t: (d / ".out.abcdefgh.old").symlink_to(t.parent),
         lambda d: files.clean_stale(d / "out")),
        ("a staging folder's .rhi-staging",
         lambda d, t: (staging_folder(d) / files.STAGING_MARK).symlink_to(t),
         lambda d: files.clean_stale(d / "out")),
        ("TMPDIR/rhi_* (a scratch folder)", lambda d, t: (d / "rhi_abc").symlink_to(t.parent),
         lambda d: scratch.clean_stale(root=d)),
        ("a scratch folder's .rhi-scratch", lambda d, t: ((d / "rhi_def").mkdir(), (d / "rhi_def" / scratch.MARK)
                                                          .symlink_to(t)),
         lambda d: scratch.clean_stale(root=d)),
        ("a sweep's trials/.NAME.tmp", lambda d, t: (a_sweep(d / "out"), (d / "out" / "trials" / ".0.json.x.tmp")
                                                     .symlink_to(t)),
         lambda d: prepare(d / "out", sweep)),
        ("any LockFile", lambda d, t: (d / "x.lock").symlink_to(t), lambda d: LockFile(d / "x.lock", "busy").acquire()),
    ]


def test_no_path_in_rhi_opens_truncates_creates_or_deletes_a_file_through_a_link(tmp_path):
    """A link at each of rhi's bookkeeping names, once to a file of the user's (its bytes and its time must stay)
    and once dangling (its target must never appear): whatever rhi does there, refuse or go on, it never acts
    through the link."""
    cases = walk_cases(tmp_path)
    assert len({case[0] for case in cases}) == len(cases)
    for number, (name, plant, use) in enumerate(cases):
        for dangling in (False, True):
            root = tmp_path / f"{number}{'d' * dangling}"
            root.mkdir()
            victim, ghost = victims(root)
            os.utime(victim, (1e9, 1e9))
            plant(root, ghost if dangling else victim)
            outside = snapshot(root / "outside")
            run_refused_or_not(lambda: use(root))
            assert snapshot(root / "outside") == outside, name
            untouched(victim, ghost)
            assert os.stat(victim).st_mtime == 1e9, name  # not opened for writing, not touched
