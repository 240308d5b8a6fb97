"""The pythonfmu FMUs (the native and kinematic bodies, the agent) declare ``initial`` as the FMI standard asks,
and FMPy's ``validate_fmu`` and ``fmutool -check`` find nothing in them (master/export/fmi_checks.py).

Truth: the FMI 2.0 standard's table of the initial values each causality and variability allows (section
2.2.7, written out in ``fmi_checks.INITIAL``): an output without a start is ``calculated``, a parameter
``exact`` with its start, an input has none.
"""
import zipfile

import pytest

from rhi.master.export.body import build_fmu
from rhi.master.export.fmi_checks import fmutool_problems, initial_problems, validate_problems, variables
from tests.test_agent import agent_fmu, quick  # noqa: F401 (fixtures)


@pytest.fixture(scope="module")
def pythonfmu_fmus(agent_fmu, tmp_path_factory):  # noqa: F811
    folder = tmp_path_factory.mktemp("initial")
    return {"native": build_fmu(folder / "Native.fmu", "native"),
            "kinematic": build_fmu(folder / "Kinematic.fmu", "kinematic"), "agent": agent_fmu}


def test_every_output_says_calculated_and_every_parameter_exact(pythonfmu_fmus):
    for name, fmu in pythonfmu_fmus.items():
        with zipfile.ZipFile(fmu) as archive:
            assert b"PythonFMU" in archive.read("modelDescription.xml")  # written by pythonfmu, completed here
        declared = variables(fmu)
        assert {c for _, c, _, _, _ in declared} >= {"input", "output", "parameter"}, name
        for variable, causality, _, initial, has_start in declared:
            expected = {"output": ("calculated", False), "parameter": ("exact", True), "input": (None, True)}
            assert (initial, has_start) == expected[causality], (name, variable)
        assert initial_problems(fmu) == [], name


def test_the_two_checkers_find_nothing(pythonfmu_fmus):
    for name, fmu in pythonfmu_fmus.items():
        assert validate_problems(fmu) == [], name
    assert fmutool_problems(pythonfmu_fmus["native"]) == []  # one: fmutool's rules do not look at the component


def test_the_initial_check_names_what_the_standard_forbids(tmp_path):
    """The check itself, on descriptions that break the table (the truth it is held to)."""
    def fmu(variable):
        path = tmp_path / f"{len(list(tmp_path.iterdir()))}.fmu"
        with zipfile.ZipFile(path, "w") as archive:
            archive.writestr("modelDescription.xml", f'<fmiModelDescription fmiVersion="2.0"><ModelVariables>'
                                                     f'{variable}</ModelVariables></fmiModelDescription>')
        return path

    cases = {
        '<ScalarVariable name="y" causality="output"><Real/></ScalarVariable>':
            "y: an output without initial (the default, calculated, left unsaid)",
        '<ScalarVariable name="y" causality="output" initial="calculated"><Real start="1"/></ScalarVariable>':
            "y: initial=calculated with a start",
        '<ScalarVariable name="p" causality="parameter" variability="fixed" initial="calculated"><Real start="1"/>'
        '</ScalarVariable>': "p: initial=calculated is not allowed for a fixed parameter (allowed: exact)",
        '<ScalarVariable name="p" causality="parameter" variability="fixed"><Real/></ScalarVariable>':
            "p: initial=exact needs a start",
        '<ScalarVariable name="u" causality="input" initial="exact"><Real start="0"/></ScalarVariable>':
            "u: initial=exact is not allowed for a continuous input (allowed: none)",
        '<ScalarVariable name="p" causality="parameter" variability="continuous"><Real start="0"/></ScalarVariable>':
            "p: causality parameter with variability continuous is not allowed",
    }
    for variable, says in cases.items():
        assert initial_problems(fmu(variable)) == [says]
    assert initial_problems(fmu('<ScalarVariable name="y" causality="output" initial="calculated"><Real/>'
                                '</ScalarVariable>')) == []
