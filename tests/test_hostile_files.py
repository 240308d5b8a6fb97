"""Hostile files: archives that try to write outside their folder or to unpack into gigabytes, output
folders that are not rhi's, and inputs that ask for unbounded work.

Each case reproduces a way a downloaded or hand-made file could make rhi write, delete or allocate what it
should not, through the command line where the behaviour is the command's (tests.faults.rhi: in this process, or
a subprocess where noted; cwd a fresh folder, TMPDIR and RHI_CACHE inside the case's own tree), or a function
where it is the unit.
"""
from __future__ import annotations

import importlib.util
import os
import re
import stat
import subprocess
import sys
import warnings
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
import torch

from rhi.components.archives import LIMITS, ArchiveError, check_archive, extract
from tests.faults import ENV, refused, rhi, snapshot, tiny_checkpoint

ONE_BODY = """<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription version="1.0" name="x" xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
 xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon" xmlns:osp="https://opensimulationplatform.com/SSP/OSPAnnotations">
<ssd:System name="x"><ssd:Elements><ssd:Component name="body" type="application/x-fmu-sharedlibrary"
 source="resources/body.fmu"/></ssd:Elements></ssd:System>
<ssd:DefaultExperiment startTime="0.0" stopTime="0.05"><ssd:Annotations><ssc:Annotation type="com.opensimulationplatform">
<osp:Algorithm><osp:FixedStepAlgorithm baseStepSize="0.01"/></osp:Algorithm></ssc:Annotation></ssd:Annotations>
</ssd:DefaultExperiment></ssd:SystemStructureDescription>
"""
SSD = ('<?xml version="1.0" encoding="UTF-8"?>\n<ssd:SystemStructureDescription version="1.0" name="x" '
       'xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"><ssd:System name="x"/>'
       '</ssd:SystemStructureDescription>\n')


# -- hostile archives, made by hand ------------------------------------------------------------------------
def member(name: str, mode: int | None = None) -> zipfile.ZipInfo:
    info = zipfile.ZipInfo(name)
    if mode is not None:
        info.external_attr = mode << 16
    return info


def write_zip(path: Path, members) -> Path:
    """``members``: (ZipInfo or name, bytes) pairs, deflated (a name twice on purpose: no warning)."""
    with warnings.catch_warnings(), zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        warnings.simplefilter("ignore", UserWarning)
        for info, data in members:
            archive.writestr(info, data)
    return path


def hostile_members(escape: Path) -> dict[str, list]:
    """Member lists that each break one rule; ``escape`` is where an escaping member would land."""
    relative = os.path.relpath(escape, "/")
    return {
        "dot_dot": [("../../../../../../../../../../" + relative, b"pwned")],
        "absolute": [(str(escape), b"pwned")],
        "symlink": [(member("resources/link", stat.S_IFLNK | 0o777), str(escape).encode())],
        "device": [(member("resources/null", stat.S_IFCHR | 0o666), b"")],
        "fifo": [(member("resources/pipe", stat.S_IFIFO | 0o666), b"")],
        "twice": [("resources/a.txt", b"one"), ("resources/a.txt", b"two")],
        "bomb": [("resources/filler.bin", bytes(LIMITS.ratio_floor * 8))],  # zeros pack about 1000:1
    }


@pytest.fixture(scope="module")
def body_fmu(tmp_path_factory):
    from rhi.master.export.body import build_fmu

    return build_fmu(tmp_path_factory.mktemp("body") / "Body.fmu", "kinematic")


def one_body_package(body: Path, out: Path, extra=()) -> Path:
    """A fair SSP package of one component (the body FMU, 5 steps of 0.01 s), with ``extra`` members."""
    return write_zip(out, [("SystemStructure.ssd", ONE_BODY), ("resources/body.fmu", body.read_bytes()), *extra])


# ======================================================================================================
# Archives never write outside their folder, and never unpack without bounds
# ======================================================================================================
@pytest.mark.parametrize("kind", list(hostile_members(Path("/x"))))
def test_a_hostile_member_is_refused_by_name_before_anything_is_unpacked(tmp_path, kind):
    escape = tmp_path / "outside" / "F"
    archive = write_zip(tmp_path / "bad.zip", [("modelDescription.xml", b"<x/>")] + hostile_members(escape)[kind])
    with pytest.raises(ArchiveError) as error:
        extract(archive, tmp_path / "into")
    assert "bad.zip: " in str(error.value) and "refused" in str(error.value)
    assert not escape.exists() and not (tmp_path / "into").exists()


def test_a_fair_archive_unpacks_whole_with_its_executable_bits(tmp_path):
    archive = write_zip(tmp_path / "ok.zip", [("a/b.txt", b"b"), (member("bin/x.so", stat.S_IFREG | 0o755), b"so"),
                                              ("c.txt", bytes(LIMITS.ratio_floor // 2))])
    folder = extract(archive, tmp_path / "into")
    assert snapshot(folder).keys() == {"a", "a/b.txt", "bin", "bin/x.so", "c.txt"}
    assert (folder / "a" / "b.txt").read_bytes() == b"b" and os.access(folder / "bin" / "x.so", os.X_OK)


def test_the_member_count_and_the_total_size_are_bounded(tmp_path):
    from rhi.components.archives import Limits

    archive = write_zip(tmp_path / "many.zip", [(f"m{i}", b"x" * 10) for i in range(11)])
    with pytest.raises(ArchiveError, match="11 members, over the limit of 10"):
        check_archive(archive, Limits(members=10))
    with pytest.raises(ArchiveError, match="unpacks to over 100 bytes"):
        check_archive(archive, Limits(total_bytes=100))
    with pytest.raises(ArchiveError, match="unpacks to 10 bytes, over the limit of 9"):
        check_archive(archive, Limits(member_bytes=9))


# every rule broken by a package; the rules whose breaking writes or fills a disk by a body inside it and by a
# body packed with export-system; FMPy's master on one (the check comes before either master)
HOSTILE_RUNS = ([(kind, "ssp-libcosim") for kind in hostile_members(Path("/x"))]
                + [(kind, what) for kind in ("dot_dot", "absolute", "bomb") for what in ("fmu-in-ssp", "export-body")]
                + [("dot_dot", "ssp-fmpy"), ("symlink", "export-body")])


@pytest.fixture(scope="module")
def hostile_runs(body_fmu, tmp_path_factory):
    """HOSTILE_RUNS: a hostile member list as an SSP for ``run-system``, as the FMU inside an SSP, or as a body
    FMU for ``export-system --body``; each run in a tree of its own."""
    root = tmp_path_factory.mktemp("hostile")
    cases = []
    for kind, what in HOSTILE_RUNS:
        case = root / f"{kind}-{what}"
        work = case / "work"
        work.mkdir(parents=True)
        bad = hostile_members(case / "outside" / "F")[kind]
        if what.startswith("ssp"):  # a package that runs (under the unchecked extraction, it wrote outside)
            one_body_package(body_fmu, work / "X.ssp", bad)
            args = ["run-system", "X.ssp", "--master", what.partition("-")[2], "--out", "out.csv"]
        elif what == "fmu-in-ssp":
            fmu = write_zip(case / "bad.fmu", [("modelDescription.xml", b"<x/>")] + bad)
            ssd = SSD.replace('<ssd:System name="x"/>', '<ssd:System name="x"><ssd:Elements><ssd:Component '
                              'name="body" source="resources/body.fmu"/></ssd:Elements></ssd:System>')
            write_zip(work / "X.ssp", [("SystemStructure.ssd", ssd), ("resources/body.fmu", fmu.read_bytes())])
            fmu.unlink()
            args = ["run-system", "X.ssp", "--out", "out.csv"]
        else:
            write_zip(work / "Bad.fmu", [("modelDescription.xml", b"<x/>")] + bad)
            args = ["export-system", "--quick", "--body", "Bad.fmu", "--out", "out.ssp"]
        cases.append((case, args, snapshot(case)))
    done = [rhi(case, *args) for case, args, _ in cases]  # in turn: an in-process run changes cwd and environment
    return [(case, args, before, result, snapshot(case)) for (case, args, before), result in zip(cases, done)]


@pytest.mark.parametrize("master", ["libcosim", "fmpy", "ecos"])
def test_a_fair_package_runs_from_its_checked_folder_under_every_master(body_fmu, tmp_path, master):
    from rhi.master.export import ssp_ecos
    if master == "ecos" and ssp_ecos.missing():
        pytest.skip(ssp_ecos.missing())
    (tmp_path / "work").mkdir()
    one_body_package(body_fmu, tmp_path / "work" / "Y.ssp")
    # own process: the run starts the master's child process
    done = rhi(tmp_path, "run-system", "Y.ssp", "--master", master, "--out", "y.csv", own_process=True)
    assert done.returncode == 0, done.stderr[-800:]
    rows = (tmp_path / "work" / "y.csv").read_text().splitlines()
    assert len(rows) == 1 + 5 and rows[-1].startswith("0.05")  # 0.05 s / 0.01 s: 5 steps after the header
    assert not any((tmp_path / "tmp").iterdir())  # the masters' unpacked copies went with rhi's folder


def test_every_hostile_archive_is_refused_in_one_line(hostile_runs):
    for case, args, before, done, after in hostile_runs:
        refused(done, "refused")
        assert "member" in done.stderr or "unpacks" in done.stderr, (case.name, done.stderr)


def test_no_command_writes_anything_anywhere_on_a_hostile_archive(hostile_runs):
    """The whole tree of each case (its working folder, TMPDIR, RHI_CACHE and the folder an escaping member
    names) is as it was, but for the empty TMPDIR and cache folders the run is given."""
    for case, args, before, done, after in hostile_runs:
        new = {path: entry for path, entry in after.items() if before.get(path) != entry}
        assert set(new) <= {"tmp", "cache"}, (case.name, new)
        assert not any(path.startswith(("tmp/", "cache/")) for path in after), (case.name, sorted(after))


# ======================================================================================================
# The body contract: distinct ports, and a body that is not a file named as such
# ======================================================================================================
def with_description(fmu: Path, out: Path, edit) -> Path:
    """A copy of ``fmu`` whose modelDescription.xml is ``edit(text)``."""
    with zipfile.ZipFile(fmu) as old, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as new:
        for info in old.infolist():
            data = old.read(info)
            new.writestr(info, edit(data.decode()).encode() if info.filename == "modelDescription.xml" else data)
    return out


def test_two_contract_ports_sharing_a_value_reference_are_refused(body_fmu, tmp_path):
    from xml.etree import ElementTree as ET

    from rhi.components.body.contract import BODY_CONTRACT
    from rhi.components.fmu import check_contract

    assert check_contract(body_fmu, BODY_CONTRACT) == []
    root = ET.fromstring(zipfile.ZipFile(body_fmu).read("modelDescription.xml"))
    reference = {v.get("name"): v.get("valueReference") for v in root.iter("ScalarVariable")}

    def alias(text):  # q_elbow given q_shoulder's value reference
        return text.replace(f'name="q_elbow" valueReference="{reference["q_elbow"]}"',
                            f'name="q_elbow" valueReference="{reference["q_shoulder"]}"')

    bad = with_description(body_fmu, tmp_path / "Alias.fmu", alias)
    assert alias(zipfile.ZipFile(body_fmu).read("modelDescription.xml").decode()) != \
        zipfile.ZipFile(body_fmu).read("modelDescription.xml").decode()  # the edit took
    assert check_contract(bad, BODY_CONTRACT) == [f"q_elbow has the value reference {reference['q_shoulder']} of q_shoulder: "
                                   "the two ports would be one value"]


def test_a_folder_or_a_device_as_body_is_named_as_such(tmp_path):
    from rhi.components.fmu import check_contract

    assert check_contract(tmp_path) == [f"{tmp_path} is a folder, not an FMU file"]
    assert check_contract("/dev/zero") == ["/dev/zero is not a regular file"]


# ======================================================================================================
# Bounds before work
# ======================================================================================================
@pytest.mark.parametrize("change, says", [
    ({"sizes.hidden": 10**8}, "sizes.hidden = 100000000 must be an integer in 1..8192"),
    ({"sizes.hidden": -5}, "sizes.hidden = -5 must be an integer"),
    ({"sizes.channels": []}, "sizes.channels = [] must be 1 to 8 integers"),
    ({"sizes.channels": [16, -8]}, "sizes.channels = [16, -8] must be"),
    ({"sizes.hidden": 128}, "its weights do not fit a conv decoder, preset 'tiny' at 16 px (its metadata describes"),  # in bounds, but not the stored weights
])
def test_a_checkpoint_s_network_sizes_are_bounded_before_anything_is_built(tmp_path, change, says):
    from rhi.components.vision.checkpoint import CheckpointError, load

    path = tiny_checkpoint(tmp_path / "c.pt", **change)
    with pytest.raises(CheckpointError, match=re.escape(says)):
        load(path)
    model, _ = load(tiny_checkpoint(tmp_path / "fair.pt"))  # the unchanged one loads
    assert model.decoder(torch.zeros(1, 2)).shape == (1, 16, 16)


# The silent listener's limits, set in the sweep's own process before main() runs (connect() reads them at each
# call): the same waiting out as under rhi.master.sweeps.runner's defaults (15 s, of which the probe's 3 s), in 4 s
# instead of 15. What is left of the limit for dask's own attempt, CONNECT_TIMEOUT_S - PROBE_S - 3 (the runner's
# margin), stays positive, as it is at the defaults: 0.4 s (a 3 s limit would leave none).
LISTENER_LIMIT_S, LISTENER_PROBE_S = 4.0, 0.6
LIMITED_SWEEP = f"""
import sys
from rhi.master.sweeps import runner
runner.CONNECT_TIMEOUT_S, runner.PROBE_S = {LISTENER_LIMIT_S}, {LISTENER_PROBE_S}
from rhi.master.commands.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_a_listener_that_is_not_a_dask_scheduler_is_refused_within_the_limit_and_leaves_no_folder(tmp_path):
    import socket
    import time

    from rhi.master.sweeps import runner
    from tests.sweep_files import sweep_file

    assert LISTENER_LIMIT_S < runner.CONNECT_TIMEOUT_S and LISTENER_LIMIT_S - LISTENER_PROBE_S - 3 > 0
    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen()  # the kernel completes the handshake; nothing ever answers
    (tmp_path / "work").mkdir()
    sweep_file(tmp_path / "work" / "s.toml", grid={"conditions.left": [-0.1]})
    # Each in its own process: its timeout is the check, and dask's threads stay out of the test's process. The
    # two at once (a folder each: a sweep holds its --out while it connects): the second's refusal comes while the
    # first waits out the limit.
    arguments = ["sweep", "--config", "s.toml", "--scheduler"]

    def timed(*more, **options):
        began = time.monotonic()
        return rhi(tmp_path, *arguments, *more, own_process=True, **options), time.monotonic() - began

    with silent, ThreadPoolExecutor(max_workers=2) as pool:
        closed = pool.submit(timed, "tls://127.0.0.1:1", "--out", "other")
        done, elapsed = timed(f"tcp://127.0.0.1:{silent.getsockname()[1]}", "--out", "out", timeout=60,
                              python=LIMITED_SWEEP)
    refused(done, f"no Dask scheduler answered within {LISTENER_LIMIT_S:g} s")  # the limit set above, waited out
    (closed, closed_took) = closed.result()
    # The limit, plus the command's start-up and refusal as long as the one refused at once took beside it (a
    # loaded machine's start-up alone has taken over 10 s), plus 5 s for the end of the waiting thread.
    assert elapsed < LISTENER_LIMIT_S + closed_took + 5
    refused(closed, "cannot reach the Dask scheduler at tls://127.0.0.1:1")
    assert sorted(p.name for p in (tmp_path / "work").iterdir()) == ["s.toml"]  # no folder left by either


def test_run_system_s_child_dies_with_its_parent(body_fmu, tmp_path):
    import signal
    import time

    work = tmp_path / "work"
    for name in ("work", "tmp", "cache"):
        (tmp_path / name).mkdir()
    long_run = ONE_BODY.replace('stopTime="0.05"', 'stopTime="9000"')  # 900,000 steps: minutes
    write_zip(work / "L.ssp", [("SystemStructure.ssd", long_run), ("resources/body.fmu", body_fmu.read_bytes())])
    parent = subprocess.Popen([sys.executable, "-m", "rhi", "run-system", "L.ssp", "--out", "l.csv"], cwd=work,
                              env={**ENV, "TMPDIR": str(tmp_path / "tmp")}, stderr=subprocess.DEVNULL)

    def children():
        found = []
        for entry in Path("/proc").iterdir():
            try:
                fields = (entry / "stat").read_text().rpartition(")")[2].split()
            except (OSError, ValueError):
                continue
            if entry.name.isdigit() and int(fields[1]) == parent.pid:
                found.append(int(entry.name))
        return found

    deadline = time.monotonic() + 20
    while not children() and time.monotonic() < deadline:
        time.sleep(0.1)
    child = children()
    assert child, "the master's child process never started"
    time.sleep(1.0)  # under way in its loop
    parent.send_signal(signal.SIGKILL)
    parent.wait()
    deadline = time.monotonic() + 5
    while Path(f"/proc/{child[0]}").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    alive = Path(f"/proc/{child[0]}/stat").exists() and (Path(f"/proc/{child[0]}/stat").read_text().rpartition(")")[2]
                                                          .split()[0] != "Z")
    if alive:
        os.kill(child[0], signal.SIGKILL)
    assert not alive, "the child ran on after its parent was killed"


@pytest.mark.parametrize("text, says", [
    ("[experiment]\ntrials = " + "9" * 400 + "\n", "has 400 digits"),
    ("[brain]\ngamma0 = " + "9" * 400 + "\n", "has 400 digits"),
    ('[experiment]\ndecoders = [["conv"]]\n', "must be a list"),
    ("[experiment]\nseed = " + "[" * 2000 + "]" * 2000 + "\n", "nests tables and arrays over 16 deep"),
    ("[brain]\ngamma0 = inf\n", "must be a finite number"),
])
def test_a_config_that_asks_for_the_unbounded_is_refused_naming_the_limit(tmp_path, text, says):
    from rhi.master.cosim import ConfigError
    from rhi.master import config

    (tmp_path / "c.toml").write_text(text)
    with pytest.raises(ConfigError, match=re.escape(says)):
        config.load(tmp_path / "c.toml")


def test_config_files_are_bounded_in_size_and_must_be_regular(tmp_path):
    from rhi.master.cosim import ConfigError
    from rhi.master import config

    with pytest.raises(ConfigError, match="/dev/zero is not a regular file"):
        config.load("/dev/zero")
    (tmp_path / "big.toml").write_text("# " + "x" * config.MAX_CONFIG_BYTES + "\n")
    with pytest.raises(ConfigError, match=f"over the limit of {config.MAX_CONFIG_BYTES} bytes"):
        config.load(tmp_path / "big.toml")


def test_inf_is_taken_where_the_docs_give_it_a_meaning_and_quoted_dotted_keys_are_dotted_keys(tmp_path):
    from rhi.master import config

    (tmp_path / "c.toml").write_text('"experiment.trials" = 3\n[brain]\naction_time_constant = inf\n'
                                     "spatial_sd = inf\n")
    loaded = config.load(tmp_path / "c.toml")
    assert loaded["experiment"]["trials"] == 3 and loaded["brain"]["action_time_constant"] == float("inf")


def test_a_grid_too_large_to_plan_is_refused_at_once(tmp_path):
    import time

    from rhi.master.cosim import ConfigError
    from rhi.master.sweeps import plan as sweeps
    from tests.sweep_files import sweep_file

    values = [round(0.001 * i, 3) for i in range(1000)]
    path = sweep_file(tmp_path / "s.toml", grid={"conditions.left": values, "conditions.right": values})
    began = time.monotonic()
    with pytest.raises(ConfigError, match=f"1000000 points, over the limit of {sweeps.MAX_POINTS}"):
        sweeps.load(path)
    assert time.monotonic() - began < 5.0  # refused before planning: the plan took about 80 min


# ======================================================================================================
# SSP packages' own bounds
# ======================================================================================================


@pytest.mark.parametrize("attribute, text, says", [
    ("stopTime", "abc", "stopTime = 'abc' is not a positive finite number"),
    ("stopTime", "inf", "stopTime = 'inf' is not a positive finite number"),
    ("baseStepSize", "0", "baseStepSize = '0' is not a positive finite number"),
    ("baseStepSize", "-0.01", "baseStepSize = '-0.01' is not a positive finite number"),
    ("stopTime", "1e300", "steps, over the limit of 1000000"),
])
def test_a_package_s_default_experiment_is_bounded_before_any_master_runs(body_fmu, tmp_path, attribute, text, says):
    from rhi.master.cosim import ConfigError
    from rhi.master.export.system import run_ssp

    original = {"stopTime": 'stopTime="0.05"', "baseStepSize": 'baseStepSize="0.01"'}[attribute]
    ssd = ONE_BODY.replace(original, f'{attribute}="{text}"')
    assert ssd != ONE_BODY
    package = write_zip(tmp_path / "P.ssp", [("SystemStructure.ssd", ssd), ("resources/body.fmu", body_fmu.read_bytes())])
    with pytest.raises(ConfigError, match=re.escape(says)):
        run_ssp(package, "fmpy")
