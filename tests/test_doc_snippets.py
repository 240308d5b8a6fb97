"""Every ```python block of README.md and docs/**/*.md runs, as a user would paste it, in a child process with a time
limit, and gives what its text says.

The markers, an HTML comment on the line right above the block's fence (invisible on the rendered page):

- ``<!-- not run: REASON -->``: the block is not run (it cannot run fast: say why);
- ``<!-- tiny: {"replace": {OLD: NEW, ...}, "check": [EXPRESSION, ...]} -->`` (a Python literal): the block runs
  with each OLD text replaced by NEW (the tiny sizes; each OLD must be in the block, so a changed snippet fails
  here rather than running as something else), then each EXPRESSION, evaluated after it, must be true: the shapes
  and values its comments state.

Any other ```python block runs as it stands.
"""
from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FENCE = re.compile(r"^```python[ \t]*\n(.*?)^```[ \t]*$", re.S | re.M)
MARKER = re.compile(r"<!--\s*(not run|tiny):\s*(.*?)\s*-->\s*\Z", re.S)
TIME_LIMIT_S = 300  # each block's child process; the tiny blocks take about 10-40 s on 2 shared cores


@dataclass
class Snippet:
    """One ```python block: where it is, its code, and its marker's content."""

    where: str
    code: str
    not_run: str | None = None
    replace: dict = field(default_factory=dict)
    check: list = field(default_factory=list)


def snippets(text: str, where: str) -> list[Snippet]:
    """The ```python blocks of a Markdown ``text``, each with the marker on the line above its fence."""
    found = []
    for match in FENCE.finditer(text):
        line = text.count("\n", 0, match.start()) + 1
        before = text[:match.start()].rstrip("\n").rsplit("\n", 1)[-1]
        snippet = Snippet(f"{where}:{line}", match.group(1))
        marker = MARKER.search(before)
        if marker and marker.group(1) == "not run":
            snippet.not_run = marker.group(2)
        elif marker:
            settings = ast.literal_eval(marker.group(2))
            snippet.replace, snippet.check = settings.get("replace", {}), settings.get("check", [])
        found.append(snippet)
    return found


def documented() -> list[Snippet]:
    files = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    return [s for path in files for s in snippets(path.read_text(encoding="utf-8"), str(path.relative_to(ROOT)))]


def runnable(snippet: Snippet) -> str:
    """The code the child runs: the block at its tiny sizes, then its checks."""
    code = snippet.code
    for old, new in snippet.replace.items():
        assert old in code, f"{snippet.where}: the marker replaces {old!r}, which the block no longer holds"
        code = code.replace(old, new)
    checks = "".join(f"assert {expression}, {expression!r}\n" for expression in snippet.check)
    return code + "\n" + checks + "print('snippet done')\n"


def test_the_parser_reads_the_markers():
    text = ("x\n<!-- not run: needs a GPU -->\n```python\nslow()\n```\n\n"
            "<!-- tiny: {'replace': {'200': '2'}, 'check': ['n == 2']} -->\n```python\nn = 200\n```\n"
            "```python\nprint(1)\n```\n```\nnot python\n```\n")
    first, second, third = snippets(text, "t.md")
    assert (first.where, first.code, first.not_run) == ("t.md:3", "slow()\n", "needs a GPU")
    assert (second.replace, second.check, second.not_run) == ({"200": "2"}, ["n == 2"], None)
    assert runnable(second) == "n = 2\n\nassert n == 2, 'n == 2'\nprint('snippet done')\n"
    assert third.code == "print(1)\n" and third.replace == {} and third.not_run is None


def test_every_not_run_block_says_why():
    for snippet in documented():
        assert snippet.not_run is None or len(snippet.not_run.split()) >= 3, snippet.where


RUN = [s for s in documented() if s.not_run is None]


@pytest.mark.parametrize("snippet", RUN, ids=[s.where for s in RUN])
def test_the_block_runs_and_gives_what_it_says(snippet, tmp_path, quick_cache):
    """As a user runs it: the block as a script file with no main guard, in a child process with a time limit,
    from the repository's root (the paths it names), the session's --quick decoders in its cache."""
    home = tmp_path / "home"
    home.mkdir()
    script = tmp_path / "snippet.py"
    script.write_text(runnable(snippet))
    environment = {**os.environ, "HOME": str(home), "RHI_CACHE": str(quick_cache),
                   "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, str(script)], cwd=ROOT, env=environment, capture_output=True,
                          text=True, timeout=TIME_LIMIT_S)
    assert done.returncode == 0, f"{snippet.where}:\n{done.stderr[-3000:]}"
    assert done.stdout.rstrip().endswith("snippet done")
