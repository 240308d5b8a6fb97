"""The floors' import graph, read from the code: which floor imports which (docs/architecture.md).

A floor is a sub-package of ``master`` (``master/tasks``), ``master`` itself for its own files (``__init__.py``,
``__main__.py``), a component folder (``components/body``), ``components`` for the component core (the modules
directly in it), and ``rhi`` for the public API. Every ``import x`` and ``from x import y`` counts, at any depth (a
lazy import inside a function too), a relative one resolved against the file's package, ``rhi.master.x`` read as
``master.x``: tests/test_layering.py reads them with :func:`imports` and checks them against its rules.

Example::

    edges = floor_edges({"master/cosim/loop.py": "", "master/tasks/run.py": "from rhi.master.cosim import x\\n"})
    # {"master/cosim": set(), "master/tasks": {"master/cosim"}}
"""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PROJECT = ("master", "components")  # the folders installed as rhi.master and rhi.components
FOLDERS = (*PROJECT, "rhi")  # the folders whose modules are floors


def folder_name(module: str) -> str:
    """``rhi.master.x`` -> ``master.x``: the installed name of a module, as the folders name it."""
    return module.removeprefix("rhi.") if module.split(".")[:2] in (["rhi", "master"], ["rhi", "components"]) \
        else module


def imports(relative: str, source: str):
    """(line, the statement, the module path it reaches) for every import in a file: ``relative`` its path from the
    project's root (``master/tasks/scene.py``), ``source`` its text."""
    parts = relative[:-3].split("/")
    package = parts[:-1]  # a module and a package's __init__ both live in their folder's package
    for node in ast.walk(ast.parse(source, relative)):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, f"import {alias.name}", folder_name(alias.name)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from the file's package, one level up per extra dot
                anchor = package[:len(package) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            for alias in node.names:
                target = base if alias.name == "*" else f"{base}.{alias.name}"
                yield (node.lineno, f"from {'.' * node.level}{node.module or ''} import {alias.name}",
                       target if node.level else folder_name(target))


def floor_of(module: str, packages: set[str]) -> str | None:
    """The floor of a dotted module path (``master.tasks.scene.build`` -> ``master/tasks``), or None outside the
    project. ``packages``: the sub-package folders there are (``master/tasks``, ``components/body``, ...)."""
    parts = module.split(".")
    if parts[0] not in FOLDERS:
        return None
    if len(parts) > 1 and f"{parts[0]}/{parts[1]}" in packages:
        return f"{parts[0]}/{parts[1]}"
    return parts[0]


def floor_edges(sources: dict[str, str]) -> dict[str, set[str]]:
    """Each floor of ``sources`` ({path from the root: text}, the .py files of :data:`FOLDERS`) -> the other floors
    its modules import."""
    packages = {"/".join(path.split("/")[:2]) for path in sources if path.count("/") >= 2}
    edges: dict[str, set[str]] = {}
    for relative, source in sources.items():
        own = floor_of(relative[:-3].replace("/", "."), packages)
        found = edges.setdefault(own, set())
        for _, _, module in imports(relative, source):
            target = floor_of(module, packages)
            if target is not None and target != own:
                found.add(target)
    return edges


def top_down(edges: dict[str, set[str]]) -> list[str]:
    """The floors by height, highest first (ties by name): a floor's height is one more than the highest floor it
    imports, 0 for one that imports none, so each floor comes before every floor it imports. ValueError naming the
    floors of a circle, which have no height."""
    floors = set(edges) | {target for targets in edges.values() for target in targets}
    height: dict[str, int] = {}
    while len(height) < len(floors):
        ready = {floor: 1 + max((height[target] for target in edges.get(floor, ())), default=-1)
                 for floor in floors - set(height) if set(edges.get(floor, ())) <= set(height)}
        if not ready:
            raise ValueError(f"the floors import one another in a circle: {', '.join(sorted(floors - set(height)))}")
        height.update(ready)
    return sorted(floors, key=lambda floor: (-height[floor], floor))


def project_sources(root: Path = ROOT) -> dict[str, str]:
    """{path from the root: text} of every .py file under :data:`FOLDERS`."""
    return {path.relative_to(root).as_posix(): path.read_text(encoding="utf-8")
            for folder in FOLDERS for path in sorted((root / folder).rglob("*.py")) if "__pycache__" not in path.parts}


def floor_table(edges: dict[str, set[str]]) -> str:
    """The graph as a Markdown table, top floor first: each floor and the floors it imports, in the same order."""
    order = top_down(edges)
    rank = {floor: number for number, floor in enumerate(order)}
    lines = ["| floor | imports (read from the code) |", "|---|---|"]
    for floor in order:
        targets = sorted(edges.get(floor, ()), key=rank.get)
        lines.append(f"| `{floor}` | {', '.join(f'`{target}`' for target in targets) or 'nothing of the project'} |")
    return "\n".join(lines)


def floor_imports() -> str:
    """docs/architecture.md's generated import graph of this checkout's floors."""
    return floor_table(floor_edges(project_sources()))
