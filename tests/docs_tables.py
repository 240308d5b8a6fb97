"""Read the generated tables of docs/ pages (between <!-- generated: NAME --> markers) as rows of cells."""
from __future__ import annotations

from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"


def block(page: str, name: str) -> str:
    text = (DOCS / page).read_text()
    start = text.index(f"<!-- generated: {name} -->\n") + len(f"<!-- generated: {name} -->\n")
    return text[start:text.index(f"\n<!-- end generated: {name} -->")]


def rows(page: str, name: str) -> list[list[str]]:
    """Every table row of the block but the header and the rule, its cells stripped (`code` marks kept)."""
    lines = [line for line in block(page, name).splitlines() if line.startswith("| ")]
    return [[cell.strip().replace("\\|", "|") for cell in line.strip()[1:-1].split(" | ")] for line in lines[1:]]


def names(page: str, name: str) -> list[str]:
    """The first column of every row, without its `code` marks."""
    return [row[0].strip("`") for row in rows(page, name)]
