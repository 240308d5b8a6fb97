"""mkdocs hook: one API reference page per module of ``components`` and ``master``, made at build time.

The pages follow the package tree by themselves: ``master/cosim/loop.py`` (``rhi.master.cosim.loop`` once installed) becomes
``api/master/cosim/loop.md`` (``::: master.cosim.loop``: griffe reads the source tree, where the folders are
``master`` and ``components``), a package's ``__init__.py`` its folder's ``index.md``, and the nav entry
``api/index.md`` in mkdocs.yml is replaced by the tree. ``__main__`` and private (``_name``) modules are left out.
Nothing is imported: mkdocstrings reads the source with griffe.
"""
from __future__ import annotations

import ast
import re
from pathlib import Path

from mkdocs.structure.files import File

PACKAGES = ("components", "master")
INDEX = "api/index.md"
OUTSIDE = re.compile(r"\[([^\]]+)\]\((\.\./[^)\s]+)\)")  # [text](../path): a file beside docs/, not in the site


def _modules(root: Path) -> list[tuple[str, str, Path]]:
    """(dotted name, page path, source file) of every public module, in package-tree order."""
    found = []
    for package in PACKAGES:
        for source in sorted((root / package).rglob("*.py")):
            parts = source.relative_to(root).with_suffix("").parts
            if any(part.startswith("_") and part != "__init__" for part in parts):
                continue  # __main__, private modules
            if not all((root.joinpath(*parts[:i]) / "__init__.py").is_file() for i in range(1, len(parts))):
                continue  # not inside a package
            if parts[-1] == "__init__":
                parts = parts[:-1]
                page = "/".join(("api", *parts, "index.md"))
            else:
                page = "/".join(("api", *parts)) + ".md"
            found.append((".".join(parts), page, source))
    return found


def _summary(source: Path) -> str:
    """The first line of a module's docstring, or ``""``."""
    docstring = ast.get_docstring(ast.parse(source.read_text(encoding="utf-8"))) or ""
    return docstring.strip().splitlines()[0] if docstring.strip() else ""


def _nav(modules: list[tuple[str, str, Path]]) -> list:
    """The nav tree of the module pages: a section per package, its own page first."""
    tree: dict = {}
    for name, page, _ in modules:
        node = tree
        for part in name.split(".")[:-1]:
            node = node.setdefault(part, {})
        if page.endswith("/index.md"):
            node.setdefault(name.split(".")[-1], {})[""] = page
        else:
            node[name.split(".")[-1]] = page

    def entries(node: dict) -> list:
        out = [node[""]] if "" in node else []
        for key in sorted(k for k in node if k):
            out.append({key: entries(node[key]) if isinstance(node[key], dict) else node[key]})
        return out

    return entries(tree)


def _replace(nav: list, modules: list[tuple[str, str, Path]]) -> bool:
    """Replace the nav entry whose page is ``api/index.md`` with that page and the module tree."""
    for i, item in enumerate(nav):
        if isinstance(item, dict):
            (title, value), = item.items()
            if value == INDEX:
                nav[i] = {title: [INDEX, *_nav(modules)]}
                return True
            if isinstance(value, list) and _replace(value, modules):
                return True
    return False


def on_files(files, config):
    """Add the API index and a virtual ``::: module`` page per module; put them in the nav."""
    root = Path(config.config_file_path).resolve().parent
    modules = _modules(root)
    lines = ["# API reference", "",
             "Generated from the docstrings at build time (`make docs`); one page per module.", ""]
    for name, page, source in modules:
        lines.append(f"- [`rhi.{name}`]({Path(page).relative_to('api').as_posix()}) {_summary(source)}".rstrip())
        files.append(File.generated(config, page, content=f"# `rhi.{name}`\n\n::: {name}\n"))
    files.append(File.generated(config, INDEX, content="\n".join(lines) + "\n"))
    if config.nav is not None:
        _replace(config.nav, modules)
    return files


def on_page_markdown(markdown, page, config, files):
    """A link out of docs/ (``[CHANGELOG.md](../CHANGELOG.md)``, right in the repository) becomes its text."""
    docs = Path(config.docs_dir).resolve()
    here = Path(page.file.abs_src_path or docs / page.file.src_path).resolve().parent

    def text(match):
        target = (here / match.group(2).split("#")[0]).resolve()
        return match.group(1) if not target.is_relative_to(docs) else match.group(0)

    return OUTSIDE.sub(text, markdown)
