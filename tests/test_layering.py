"""Imports go one way: the rule table below, checked on every .py file under master/ and components/.

Every ``import x`` and ``from x import y`` counts, at any depth (a lazy import inside a function too);
a relative import is resolved against the file's package. The folders are installed as ``rhi.master`` and
``rhi.components``: the rules speak of ``master.x`` and ``components.x``, and an import of ``rhi.master.x``
counts as one of ``master.x`` (:func:`rhi.master.reference.imports.imports` reads them). docs/architecture.md
mirrors the table and shows the floors' import graph that reading gives.
"""
import ast
from pathlib import Path

import pytest

from rhi.master.reference.imports import imports  # the one reading of imports, docs/architecture.md's graph's too

ROOT = Path(__file__).resolve().parents[1]

# -- the rules, as data --------------------------------------------------------------------------
# master's sub-packages by layer, top first. A sub-package may import itself and any lower layer;
# never a higher layer, nor another member of its own layer (sweeps/bench). export sits on tasks: the
# agent it exports is the experiment's system without its body (master/export/agent.py). reference writes
# docs/'s tables from everything below it.
MASTER_LAYERS = [("commands",), ("reference",), ("phenomena", "fit", "studies"), ("sweeps", "bench"), ("export",),
                 ("tasks",), ("decoders",), ("config",), ("models",), ("runtime",), ("outputs",), ("cosim",)]
# master's own files outside the sub-packages, and the sub-packages each may import.
MASTER_FILES = {"master/__init__.py": ("cosim",), "master/__main__.py": ("commands",)}
# ``from master import X`` (not a sub-package) reaches master/__init__.py, which re-exports this one:
MASTER_ROOT_IS = "cosim"
# Only these import master.commands (a folder ends with /).
COMMANDS_IMPORTERS = ("master/__main__.py", "master/commands/")
# Of this project, the engine imports only these modules (and the packages above them).
COSIM_MAY_IMPORT = ("master.cosim", "components.component", "components.variables")
COSIM_FORBIDDEN_WORDS = ("decoder", "drift", "gamma", "rubber", "brain")
# components/ never imports master. A component folder imports the core and itself, no other folder;
# a module directly in components/ (stimulus, the core) imports the core only. fmi_export (a component as an
# FMU) is a folder like the others: no component imports it (the body FMUs' slave scripts load it by its path
# from their bundled copy), and fmu (an FMU as a component) is its opposite.
COMPONENT_CORE = ("components.component", "components.variables", "components.model_description",
                  "components.archives")
COMPONENT_FOLDERS = ("body", "vision", "brain", "fmu", "fmi_export")
PROJECT = ("master", "components")  # top-level packages whose imports are checked


def within(module: str, prefixes) -> bool:
    """``module`` is one of ``prefixes`` or inside one (dotted boundaries)."""
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def rank(layer: str) -> int:
    return next(i for i, members in enumerate(MASTER_LAYERS) if layer in members)


def master_layer(module: str) -> str:
    """The sub-package of master that ``module`` (inside master) reaches."""
    parts = module.split(".")
    known = [member for members in MASTER_LAYERS for member in members]
    return parts[1] if len(parts) > 1 and parts[1] in known else MASTER_ROOT_IS


def master_problem(relative: str, module: str) -> str | None:
    """Why a file of master/ may not import ``module`` (a project module), or None."""
    parts = relative.split("/")
    if module.split(".")[0] == "components":
        if parts[1] == "cosim" and not within(module, COSIM_MAY_IMPORT):
            return f"master/cosim imports from components only {', '.join(COSIM_MAY_IMPORT[1:])}"
        return None
    if parts[1] == "cosim" and not within(module, COSIM_MAY_IMPORT):
        return "master/cosim imports nothing of master outside master/cosim"
    target = master_layer(module)
    if target == "commands" and not (relative in COMMANDS_IMPORTERS or relative.startswith(COMMANDS_IMPORTERS[1])):
        return "only master/__main__.py and master/commands import master.commands"
    if relative in MASTER_FILES:
        allowed = MASTER_FILES[relative]
        return None if target in allowed else f"{relative} imports only master.{', master.'.join(allowed)}"
    source = parts[1]
    if target == source or rank(target) > rank(source):
        return None
    side = "beside" if rank(target) == rank(source) else "above"
    return f"master/{source} may not import master/{target}, a layer {side} it"


def component_problem(relative: str, module: str) -> str | None:
    """Why a file of components/ may not import ``module`` (a project module), or None."""
    if module.split(".")[0] == "master":
        return "components never import master"
    parts = relative.split("/")
    folder = parts[1] if len(parts) > 2 else None
    own = (f"components.{folder}",) if folder else ()
    if within(module, COMPONENT_CORE + own):
        return None
    where = f"components/{folder}" if folder else relative
    return f"{where} imports of components only the core ({', '.join(COMPONENT_CORE)}){' and itself' * bool(folder)}"


def violations(relative: str, source: str) -> list[str]:
    """Every broken rule in one file, as ``file:line: import: rule``."""
    parts = relative.split("/")
    if parts[0] == "master" and len(parts) == 2 and relative not in MASTER_FILES:
        return [f"{relative}:1: a module of master outside the layer table"]
    if parts[0] == "master" and len(parts) > 2 and not any(parts[1] in members for members in MASTER_LAYERS):
        return [f"{relative}:1: master/{parts[1]} is not in the layer table"]
    if parts[0] == "components" and len(parts) > 2 and parts[1] not in COMPONENT_FOLDERS:
        return [f"{relative}:1: components/{parts[1]} is not in the rule table"]
    found = []
    for line, statement, module in imports(relative, source):
        if module.split(".")[0] not in PROJECT:
            continue
        problem = (master_problem if parts[0] == "master" else component_problem)(relative, module)
        if problem:
            found.append(f"{relative}:{line}: {statement}: {problem}")
    return found


def python_files(*folders):
    return sorted(p for folder in folders for p in (ROOT / folder).rglob("*.py") if "__pycache__" not in p.parts)


def test_imports_follow_the_rule_table():
    files = python_files("master", "components")
    assert len(files) > 40 and any(p.parent.name == "cosim" for p in files)
    found = [v for path in files for v in violations(path.relative_to(ROOT).as_posix(), path.read_text())]
    assert not found, "\n".join(found)


def absolute_imports(path: Path):
    """(line, module) of every absolute import in a file, at any depth."""
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            yield from ((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and not node.level:
            yield node.lineno, node.module


def test_imports_name_the_installed_package():
    """The distribution installs ``rhi`` only: master/, tests/ and examples/ import ``rhi.master`` and
    ``rhi.components``, never a bare ``master`` or ``components``; components/ imports itself relatively, so that
    the copy a body FMU carries (as its own top-level ``components``) runs where rhi is not installed."""
    found = []
    for path in python_files("master", "components", "tests", "examples", "rhi"):
        for line, module in absolute_imports(path):
            top = module.split(".")[0]
            inside_components = path.relative_to(ROOT).parts[0] == "components"
            if top in PROJECT or (inside_components and within(module, ("rhi",))):
                found.append(f"{path.relative_to(ROOT)}:{line}: import {module}")
    assert not found, "\n".join(found)


def test_engine_knows_no_rubber_hand_words():
    found = []
    for path in python_files("master/cosim"):
        for number, line in enumerate(path.read_text().splitlines(), 1):
            found += [f"{path.relative_to(ROOT)}:{number}: {word!r}: {line.strip()}"
                      for word in COSIM_FORBIDDEN_WORDS if word in line.lower()]
    assert not found, "\n".join(found)


@pytest.mark.parametrize("relative, source, expected", [
    ("master/cosim/loop.py", "def f():\n    from master.tasks.illusion import wiring\n", "loop.py:2:"),
    ("master/cosim/loop.py", "import master\n", "master/cosim imports nothing"),
    ("master/cosim/loop.py", "from ..outputs import files\n", "master/cosim imports nothing"),
    ("master/cosim/loop.py", "from components.body import plant\n", "from components only"),
    ("master/cosim/loop.py", "import components.fmu\n", "from components only"),
    ("master/outputs/files.py", "from master.tasks.illusion.measures import measures\n", "a layer above it"),
    ("master/tasks/illusion/wiring.py", "from master.export import body\n", "a layer above it"),
    ("master/sweeps/plan.py", "import master.bench.suite\n", "a layer beside it"),
    ("master/sweeps/plan.py", "from master.phenomena import report\n", "a layer above it"),
    ("master/phenomena/report.py", "from master.commands import cli\n", "only master/__main__.py"),
    ("master/bench/suite.py", "from master.commands import cli\n", "only master/__main__.py"),
    ("master/__init__.py", "from master.tasks.illusion import wiring\n", "imports only master.cosim"),
    ("master/extra.py", "", "outside the layer table"),
    ("components/stimulus.py", "from master.cosim import System\n", "never import master"),
    ("components/body/camera.py", "from components.vision.component import Decoder\n", "only the core"),
    ("components/brain/integrator.py", "from components import stimulus\n", "only the core"),
    ("components/fmu/adapter.py", "from components.body.plant import ArmPlant\n", "only the core"),
    ("components/vision/fast.py", "from ..fmu import adapter\n", "only the core"),
    ("components/body/plant.py", "from ..fmi_export.calls import step\n", "only the core"),
    ("components/component.py", "from .fmi_export import bundle\n", "only the core"),
    ("components/fmi_export/slave_fmi3.py", "from ..body.contract import FMI3_ARRAYS\n", "only the core"),
    ("components/fmi_export/calls.py", "from ..fmu.adapter import FMUComponent\n", "only the core"),
])
def test_the_checker_catches_each_kind_of_violation(relative, source, expected):
    found = violations(relative, source)
    assert len(found) == 1 and expected in found[0], found


@pytest.mark.parametrize("relative, source", [
    ("master/cosim/loop.py", "from master.cosim.system import System\nfrom components.component import Status\n"),
    ("master/cosim/links.py", "from .system import split\n"),
    ("master/commands/cli.py", "from master.sweeps import plan\nfrom master.commands import bench\n"),
    ("master/sweeps/runner.py", "from master.tasks.illusion import runner\nfrom master import ConfigError\n"),
    ("master/phenomena/report.py", "from master.sweeps import plan\nfrom master.outputs import figures\n"),
    ("master/export/body.py", "from master.cosim import ConfigError\nimport numpy\n"),
    ("master/export/agent.py", "from master.tasks.illusion import wiring\n"),
    ("master/__main__.py", "from master.commands.cli import main\n"),
    ("components/body/variants.py", "from components.body.plant import ArmPlant\nfrom .kinematics import forward\n"),
    ("components/vision/component.py", "from components.model_description import to_xml\n"),
    ("components/fmi_export/slave_fmi3.py", "from .calls import step\nfrom ..model_description import xml_value\n"),
])
def test_the_checker_allows_what_the_table_allows(relative, source):
    assert violations(relative, source) == []


# -- no import circles ---------------------------------------------------------------------------------
def module_name(relative: str) -> str:
    """``master/config/__init__.py`` -> ``master.config`` (a package's ``__init__`` is the package)."""
    parts = relative[:-3].split("/")
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def circles(sources: dict[str, str]) -> list[list[str]]:
    """Every import circle among the modules ``{relative path: source}``, as the sorted modules of each strongly
    connected part of the import graph (any import, at any depth, counts, as for the rule table; importing a
    module runs its packages' ``__init__`` too, but a module's own packages are not counted as its imports)."""
    names = {module_name(relative): relative for relative in sources}
    graph = {}
    for name, relative in names.items():
        edges = set()
        for _, _, target in imports(relative, sources[relative]):
            parts = target.split(".")
            while parts and ".".join(parts) not in names:
                parts.pop()
            for depth in range(1, len(parts) + 1):  # the module and the packages above it
                reached = ".".join(parts[:depth])
                if reached in names and reached != name and not name.startswith(reached + "."):
                    edges.add(reached)
        graph[name] = edges
    # Tarjan's strongly connected components, iteratively (no recursion limit to meet).
    index, low, on_stack, stack, found, counter = {}, {}, set(), [], [], 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                part = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    part.append(member)
                    if member == node:
                        break
                if len(part) > 1:
                    found.append(sorted(part))
    return found


def test_no_import_circles():
    sources = {path.relative_to(ROOT).as_posix(): path.read_text() for path in python_files("master", "components")}
    assert circles(sources) == []


@pytest.mark.parametrize("sources, expected", [
    ({"master/a/x.py": "from master.a import y\n", "master/a/y.py": "def f():\n    from master.a.x import g\n"},
     [["master.a.x", "master.a.y"]]),
    ({"master/a/__init__.py": "from master.a.x import f\n", "master/a/x.py": "", "master/b/y.py": "import master.a.x\n",
      "master/a/z.py": "from master.b import y\n", "master/b/__init__.py": ""}, []),
    ({"master/a/__init__.py": "from master.a.z import f\n", "master/a/z.py": "from master.b.y import g\n",
      "master/b/__init__.py": "", "master/b/y.py": "from master.a import h\n"},
     [["master.a", "master.a.z", "master.b.y"]]),
])
def test_the_circle_finder_finds_each_circle(sources, expected):
    assert circles(sources) == expected
