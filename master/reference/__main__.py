"""``python -m rhi.master.reference [--check]``: rewrite docs/'s generated tables from the code, or list stale ones."""
from __future__ import annotations

import re
import sys
from pathlib import Path

from rhi.master.reference.tables import TABLES

DOCS = Path(__file__).resolve().parents[2] / "docs"
BLOCK = re.compile(r"(<!-- generated: ([\w-]+) -->\n)(.*?)(<!-- end generated: \2 -->)", re.S)


def regenerate(text: str, tables: dict[str, str]) -> str:
    """``text`` with every generated block's body replaced by its table (an unknown name raises KeyError)."""
    return BLOCK.sub(lambda m: m.group(1) + tables[m.group(2)] + "\n" + m.group(4), text)


def blocks(text: str) -> dict[str, str]:
    """Each generated block's body, by name, without its last newline."""
    return {m.group(2): m.group(3).removesuffix("\n") for m in BLOCK.finditer(text)}


def main(argv: list[str]) -> int:
    """Rewrite the stale generated tables of docs/*.md, or with ``--check`` only name them.

    Parameters
    ----------
    argv : list of str
        The command's arguments: ``["--check"]`` or none.

    Returns
    -------
    int
        The exit status: 1 when ``--check`` found a stale table, else 0.
    """
    pages = sorted(DOCS.glob("*.md"))
    names = {name for page in pages for name in blocks(page.read_text())}
    tables = {name: TABLES[name]() for name in sorted(names)}
    stale = []
    for page in pages:
        text = page.read_text()
        new = regenerate(text, tables)
        if new != text:
            stale.append(page.name)
            if "--check" not in argv:
                page.write_text(new)
    if "--check" in argv and stale:
        print(f"stale generated tables in docs/{', docs/'.join(stale)}: run python -m rhi.master.reference", file=sys.stderr)
        return 1
    print(("rewrote " + ", ".join(stale)) if stale and "--check" not in argv else "docs/ tables are current")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
