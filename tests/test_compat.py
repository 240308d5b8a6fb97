"""The compatibility matrix of docs/fmi.md (master/export/compat.py, master/export/compat_checks.py): the stored
results are whole (every FMU x every check and master, no cell untested, a reason for every cell that is not a
pass), the docs show exactly them, a reference CSV is shipped for every row, and a cheap part measured again
gives the same cells.

Truth: the measurement itself, repeated (the C body's FMI 3.0 row, whose masters start in a second without
torch; the agent's static checks and package schema, on the FMU the session builds), the FMI 2.0 twins under
FMPy, the body's resting pose (rhi.components.body.kinematics), and the band fmpy.util.validate_result draws
(10 % of a constant signal's value).
"""
import importlib.util
import json

import numpy as np
import pytest
from fmpy.util import read_csv

from rhi.components.body.kinematics import REST_POSE
from rhi.master.export import compat, ssp_ecos
from rhi.master.export.compat_checks import package, reference_problems, schema_problems, twice_problems
from rhi.master.export.fmi_checks import CHECKS
from tests.docs_tables import block
from tests.test_agent import agent_fmu, quick  # noqa: F401 (fixtures)

MASTERS_HERE = importlib.util.find_spec("libcosimpy") is not None and ssp_ecos.missing() is None
C2, C3 = ("body", "kinematic-c", "2.0"), ("body", "kinematic-c", "3.0")


@pytest.fixture(scope="module")
def stored():
    return json.loads(compat.RESULTS.read_text(encoding="utf-8"))["matrix"]


@pytest.fixture(scope="module")
def c_bodies(tmp_path_factory):
    return compat.build(tmp_path_factory.mktemp("compat"), {}, [C2, C3])


def test_the_stored_matrix_is_whole_and_every_cell_not_a_pass_says_why(stored):
    assert list(stored) == [compat.row_name(row) for row in compat.ROWS]
    assert compat.row_name(("agent", "reach", "2.0")) in stored
    for name, cells in stored.items():
        assert list(cells) == list(compat.COLUMNS), name
        for column, (result, reason) in cells.items():
            assert result in (compat.PASS, compat.FAIL, compat.UNSUPPORTED), (name, column)
            assert bool(reason) == (result != compat.PASS), (name, column)
            assert "untested" not in (result + reason).lower()
    assert block("fmi.md", "fmi-compat") == compat.table(stored)  # the docs show the stored results


def test_every_row_has_a_reference_csv_of_64_steps_from_time_0():
    for row in compat.ROWS:
        reference = read_csv(compat.reference_path(row))
        assert reference.dtype.names[0] == "time"
        np.testing.assert_array_equal(reference["time"], np.arange(compat.REFERENCE_STEPS + 1) * compat.STEP)


@pytest.mark.skipif(not MASTERS_HERE, reason="libcosimpy or ecospy is not installed (the test extra)")
def test_the_c_bodys_fmi3_row_measured_again_gives_the_stored_cells(stored, c_bodies):
    measured = compat.measure(c_bodies, [C3])
    assert measured == {compat.row_name(C3): stored[compat.row_name(C3)]}
    assert all(measured[compat.row_name(C3)][c] == [compat.PASS, ""]
               for c in (compat.SCHEMA, compat.TWICE, compat.REFERENCE))


def test_the_agents_static_checks_and_schema_measured_again_give_the_stored_cells(stored, agent_fmu):  # noqa: F811
    name = compat.row_name(("agent", "illusion", "2.0"))
    static = [c for c in CHECKS if c != "fmutool -check"] + [compat.SCHEMA]  # fmutool: the C body's row runs it
    assert compat.measure({("agent", "illusion", "2.0"): agent_fmu}, [("agent", "illusion", "2.0")], static) == {
        name: {c: stored[name][c] for c in static}}


def test_the_c_bodys_references_hold_its_resting_pose_and_its_fmi3_arrays_are_its_fmi2_outputs_to_the_bit():
    fmi2, fmi3 = read_csv(compat.reference_path(C2)), read_csv(compat.reference_path(C3))
    assert fmi3.dtype.names == ("time", "q", "hand", "force") and fmi3["q"].shape == (65, 2)
    assert np.all(fmi3["q"] == REST_POSE)  # its command held at 0: it stays at rest
    np.testing.assert_array_equal(fmi3["q"], np.stack([fmi2["q_shoulder"], fmi2["q_elbow"]], axis=-1))
    np.testing.assert_array_equal(fmi3["hand"], np.stack([fmi2["hand_x"], fmi2["hand_y"]], axis=-1))


@pytest.mark.parametrize("variant", ["native", "kinematic"])
def test_the_pythonfmu_bodies_fmi3_references_are_their_fmi2_references_to_the_bit(variant):
    fmi2, fmi3 = (read_csv(compat.reference_path(("body", variant, fmi))) for fmi in ("2.0", "3.0"))
    assert fmi3.dtype.names == ("time", "q", "hand", "force")
    for array, (first, second) in (("q", ("q_shoulder", "q_elbow")), ("hand", ("hand_x", "hand_y")),
                                   ("force", ("force_x", "force_y"))):
        np.testing.assert_array_equal(fmi3[array], np.stack([fmi2[first], fmi2[second]], axis=-1))


def test_the_reference_comparison_takes_last_bits_and_validate_results_band_and_no_more():
    reference = read_csv(compat.reference_path(C3))
    assert reference_problems(reference.copy(), reference) == []
    ulp = reference.copy()
    ulp["q"] = np.nextafter(ulp["q"], np.inf)  # another CPU's last bit, every sample
    assert reference_problems(ulp, reference) == []
    within, beyond = reference.copy(), reference.copy()
    within["hand"][30, 1] += 0.04  # hand_y, constant 0.5: its band is 10 % of it, 0.05
    beyond["hand"][30, 1] += 0.06
    assert reference_problems(within, reference) == []
    assert reference_problems(beyond, reference) == ["hand[2]: 2% of its samples outside validate_result's band"]
    assert reference_problems(reference[:40].copy(), reference) == ["ends at 0.609375 s, the reference at 1.0 s"]


def test_the_reference_comparison_holds_non_finite_samples_exactly():
    reference = read_csv(compat.reference_path(("agent", "illusion", "2.0")))
    assert np.all(reference["visual_time"] == -np.inf) and np.isnan(reference["free_energy"][0])
    touched = reference.copy()
    touched["visual_time"][10] = 0.15625  # an event the reference does not have
    assert reference_problems(touched, reference) == ["visual_time: not the reference's non-finite samples"]


def test_instantiating_the_c_body_again_after_freeing_it_gives_its_first_step_to_the_bit(c_bodies, tmp_path):
    names = compat.outputs(c_bodies[C2])
    assert twice_problems(c_bodies[C2], {}, names, compat.STEP, tmp_path) == []
    with np.load(tmp_path / "out.npz") as values:
        assert values["q_shoulder.1"].tobytes() == values["q_shoulder.2"].tobytes() == \
            np.array([REST_POSE[0]]).tobytes()


def test_the_ssp_schema_check_names_what_breaks_the_parameter_set(c_bodies, tmp_path):
    ssp = package(c_bodies[C2], tmp_path, {"q_shoulder": 1.0}, 5 * compat.STEP, compat.STEP)
    assert schema_problems(ssp) == []
    ssv = ssp / "resources" / "fmu.ssv"
    ssv.write_text(ssv.read_text().replace("<ssv:Real value=", "<ssv:Real valu="))
    assert schema_problems(ssp) == [
        "resources/fmu.ssv line 3: Element '{http://ssp-standard.org/SSP1/SystemStructureParameterValues}Real', "
        "attribute 'valu': The attribute 'valu' is not allowed.",
        "resources/fmu.ssv line 3: Element '{http://ssp-standard.org/SSP1/SystemStructureParameterValues}Real': "
        "The attribute 'value' is required but missing."]
