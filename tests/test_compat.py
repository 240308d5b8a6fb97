"""The compatibility matrix of docs/fmi.md (master/export/compat.py): the stored results are whole (every FMU x
every check and master, no cell untested, a reason for every cell that is not a pass), the docs show exactly
them, and a cheap part measured again here gives the same cells.

Truth: the measurement itself, repeated (the C body's FMI 3.0 row, whose masters start in a second without
torch; the agent's static checks, on the FMU the session builds), and the FMI 2.0 twins under FMPy.
"""
import importlib.util
import json

import pytest

from master.export import compat, ssp_ecos
from master.export.fmi_checks import CHECKS
from tests.docs_tables import block
from tests.test_agent import agent_fmu, quick  # noqa: F401 (fixtures)

MASTERS_HERE = importlib.util.find_spec("libcosimpy") is not None and ssp_ecos.missing() is None


@pytest.fixture(scope="module")
def stored():
    return json.loads(compat.RESULTS.read_text(encoding="utf-8"))["matrix"]


def test_the_stored_matrix_is_whole_and_every_cell_not_a_pass_says_why(stored):
    assert list(stored) == [compat.row_name(row) for row in compat.ROWS]
    for name, cells in stored.items():
        assert list(cells) == list(compat.COLUMNS), name
        for column, (result, reason) in cells.items():
            assert result in (compat.PASS, compat.FAIL, compat.UNSUPPORTED), (name, column)
            assert bool(reason) == (result != compat.PASS), (name, column)
            assert "untested" not in (result + reason).lower()
    assert block("fmi.md", "fmi-compat") == compat.table(stored)  # the docs show the stored results


@pytest.mark.skipif(not MASTERS_HERE, reason="libcosimpy or ecospy is not installed (the test extra)")
def test_the_c_bodys_fmi3_row_measured_again_gives_the_stored_cells(stored, tmp_path):
    rows = [("body", "kinematic-c", "2.0"), ("body", "kinematic-c", "3.0")]
    fmus = compat.build(tmp_path, {}, rows)
    measured = compat.measure(fmus, rows[1:])
    assert measured == {compat.row_name(rows[1]): stored[compat.row_name(rows[1])]}


def test_the_agents_static_checks_measured_again_give_the_stored_cells(stored, agent_fmu):  # noqa: F811
    name = compat.row_name(("agent", "illusion", "2.0"))
    static = [c for c in CHECKS if c != "fmutool -check"]  # fmutool: the C body's row above runs it
    assert compat.measure({("agent", "illusion", "2.0"): agent_fmu}, [("agent", "illusion", "2.0")], static) == {
        name: {c: stored[name][c] for c in static}}
