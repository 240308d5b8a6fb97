"""An SSP package's parameter values, checked before any master runs (master/export/ssp_check.py), and a
component that refuses its values as it starts, in its own words under FMPy and libcosim (ssp_runner.py), named
as refused under Ecos.

Truth: FMI 2.0's types (an Integer is a C int; libcosim reads no NaN or INF), the ranges the FMUs declare,
and the brain's own rule (Sigma_p positive and finite, components/brain/base.py).
"""
import importlib.util
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from rhi.master.cosim import ConfigError
from rhi.master.export import ssp_ecos
from rhi.master.export.ssp_check import read_ssp
from rhi.master.export.ssp_ecos import ECOS_FAILED as ssp_ecos_failed
from tests.in_process import rhi_in_process
from tests.test_agent import agent_fmu, quick  # noqa: F401 (fixtures)
from tests.test_ssp_export import package  # noqa: F401 (fixture)

LIBCOSIM = importlib.util.find_spec("libcosimpy") is not None
TRIAL = "resources/trials/conv_left_sync_0.ssv"  # the trial the package binds
BODY = "resources/body.ssv"


def with_value(package, target, member, name, value):  # noqa: F811
    """A copy of ``package`` whose parameter file ``member`` sets ``name`` to the text ``value``."""
    with zipfile.ZipFile(package) as old, zipfile.ZipFile(target, "w") as new:
        for item in old.infolist():
            data = old.read(item.filename)
            if item.filename == member:
                data, count = re.subn(rf'(<ssv:Parameter name="{name}">\s*<ssv:\w+ value=")[^"]*',
                                      rf"\g<1>{value}", data.decode())
                assert count == 1, (member, name)
                data = data.encode()
            new.writestr(item, data)
    return target


def rhi(*args):
    return subprocess.run([sys.executable, "-m", "rhi", *args], capture_output=True, text=True, timeout=120)


BAD_VALUES = [  # (file, parameter, text, what the refusal says)
    (TRIAL, "period", "nan", "sets agent.period to 'nan', not a finite Real"),
    (TRIAL, "period", "INF", "sets agent.period to 'INF', not a finite Real"),
    (TRIAL, "period", "1e400", "sets agent.period to '1e400', not a finite Real"),  # beyond a double: inf
    (TRIAL, "period", "1_0", "sets agent.period to '1_0', not a finite Real"),  # Python's float takes it
    (BODY, "held", "maybe", "sets body.held to 'maybe', not a Boolean (true, false, 1 or 0)"),
    (TRIAL, "seed", str(2 ** 31), "sets agent.seed to '2147483648', not an Integer within [-2147483648, 2147483647]"),
    (BODY, "substeps", "1.5", "sets body.substeps to '1.5', not an Integer within"),
    (TRIAL, "gamma0", "2", "sets agent.gamma0 = 2, outside the range [0, 1] its FMU declares"),
    (TRIAL, "period", "0.0001", "sets agent.period = 0.0001, outside the range [0.001, inf] its FMU declares"),
]


@pytest.mark.parametrize("member, name, text, says", BAD_VALUES, ids=[f"{c[1]}={c[2]}" for c in BAD_VALUES])
def test_a_value_not_of_its_type_or_outside_its_declared_range_is_refused_by_the_check(
        package, tmp_path, member, name, text, says):  # noqa: F811
    bad = with_value(package, tmp_path / "bad.ssp", member, name, text)
    with pytest.raises(ConfigError) as refused:
        read_ssp(bad)
    assert f"bad.ssp: {member} {says}" in str(refused.value)


def test_the_edges_of_each_type_pass_the_check(package, tmp_path):  # noqa: F811
    edges = with_value(package, tmp_path / "e.ssp", TRIAL, "seed", str(-2 ** 31))
    edges = with_value(edges, tmp_path / "e2.ssp", TRIAL, "gamma0", "1")
    edges = with_value(edges, tmp_path / "e3.ssp", BODY, "held", "0")
    read_ssp(edges)


def test_a_bad_value_is_refused_in_one_line_before_any_master_starts(package, tmp_path, monkeypatch):  # noqa: F811
    from rhi.master.export import system

    bad = with_value(package, tmp_path / "bad.ssp", TRIAL, "period", "nan")
    # refused before any master: main() in this process (tests/in_process.py), as a subprocess would give it
    done = rhi_in_process(["run-system", str(bad), "--master", "libcosim" if LIBCOSIM else "fmpy", "--out",
                           str(tmp_path / "o.csv")], Path.cwd(), {})
    lines = done.stderr.strip().splitlines()
    assert done.status == 2 and len(lines) == 1 and "not a finite Real" in lines[0], done.stderr
    assert not (tmp_path / "o.csv").exists()

    def no_master(*args, **kwargs):  # the child process a master runs in
        raise AssertionError("a master was started")

    monkeypatch.setattr(system.subprocess, "run", no_master)
    with pytest.raises(ConfigError, match="not a finite Real"):
        system.run_ssp(bad, "fmpy")


@pytest.mark.parametrize("master", ["fmpy", "libcosim", "ecos"])
def test_a_value_the_agent_refuses_as_it_starts_is_named_in_its_own_words(package, tmp_path, master):  # noqa: F811
    if master == "libcosim" and not LIBCOSIM:
        pytest.skip("libcosimpy is not installed (the test extra)")
    if master == "ecos" and ssp_ecos.missing():
        pytest.skip(ssp_ecos.missing())
    bad = with_value(package, tmp_path / "zero.ssp", TRIAL, "proprioceptive_variance", "0")  # in [0, inf], as declared
    # a process of its own: the refusal comes from the master's child, as the FMU starts
    done = rhi("run-system", str(bad), "--master", master, "--out", str(tmp_path / "o.csv"))
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    # Ecos applies the bound file itself (its parameter set, by name) and so starts the agent with the 0; it
    # neither checks an FMU's status nor passes on its messages, so the reason is not the agent's own words
    reason = (ssp_ecos_failed if master == "ecos" else
              "brain.proprioceptive_variance must be positive and finite, got 0.0")
    assert lines[0] == f"rhi run-system: error: zero.ssp: {reason} (refused as the FMU started under {master})"
    assert not (tmp_path / "o.csv").exists()
