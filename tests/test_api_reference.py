"""The API reference (mkdocs.yml, docs/api_pages.py): the site builds strict, a page per module, and every public
function, class and method of the covered packages has a docstring to show there (read with ast: nothing imported)."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# The package folders whose public names must all have docstrings (each with everything below it).
COVERED = ("components", "master")
# Folders below those left out: none (every folder of master/ is covered).
NOT_COVERED = ()


def test_the_site_builds_strict_with_a_page_per_module(tmp_path):
    site = tmp_path / "site"
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-4000:]
    assert "simulate" in (site / "api" / "master" / "cosim" / "index.html").read_text()
    assert "def step_count" not in (site / "api" / "master" / "cosim" / "loop" / "index.html").read_text()
    assert "step_count" in (site / "api" / "master" / "cosim" / "loop" / "index.html").read_text()
    assert "Variable" in (site / "api" / "components" / "variables" / "index.html").read_text()
    assert (site / "api" / "index.html").is_file() and (site / "design" / "index.html").is_file()
    assert not (site / "api" / "master" / "__main__").exists(), "__main__ modules are left out"
    for source in ROOT.glob("master/*/__init__.py"):
        assert (site / "api" / "master" / source.parent.name / "index.html").is_file(), source


def _public(name: str) -> bool:
    return not name.startswith("_")


def _undocumented(source: Path) -> list[str]:
    """``path:line name`` of each public module-level function or class, or public method of a public class,
    without a docstring. Property setters and deleters, and ``@overload`` stubs, need none."""
    tree = ast.parse(source.read_text(encoding="utf-8"), filename=str(source))
    where = source.relative_to(ROOT).as_posix()
    missing = []
    functions = (ast.FunctionDef, ast.AsyncFunctionDef)

    def exempt(node) -> bool:
        for decorator in node.decorator_list:
            if isinstance(decorator, ast.Attribute) and decorator.attr in ("setter", "deleter"):
                return True
            if isinstance(decorator, ast.Name) and decorator.id == "overload":
                return True
        return False

    for node in tree.body:
        if isinstance(node, (*functions, ast.ClassDef)) and _public(node.name):
            if ast.get_docstring(node) is None:
                missing.append(f"{where}:{node.lineno} {node.name}")
            if isinstance(node, ast.ClassDef):
                for member in node.body:
                    if (isinstance(member, functions) and _public(member.name) and not exempt(member)
                            and ast.get_docstring(member) is None):
                        missing.append(f"{where}:{member.lineno} {node.name}.{member.name}")
    return missing


def test_every_public_function_class_and_method_has_a_docstring():
    sources = sorted({source for folder in COVERED for source in (ROOT / folder).rglob("*.py")
                      if (_public(source.stem) or source.stem in ("__init__", "__main__"))
                      and not any(source.is_relative_to(ROOT / left) for left in NOT_COVERED)})
    assert sources, COVERED
    missing = [entry for source in sources for entry in _undocumented(source)]
    assert not missing, f"{len(missing)} without a docstring:\n" + "\n".join(missing)
