"""What rhi wrote, by kind: the checks ``--force`` applies before ``rhi export-body``, ``export-agent``,
``export-system`` or ``run-system`` replaces an existing ``--out FILE`` (docs/configuration.md: --out never
deletes anything rhi did not write).

Each check reads only what identifies the file (a zip's directory and one small member, a CSV's first lines,
within bounds) and returns None for a file rhi wrote, else what it is not. A file is rhi's:

- ``.fmu``: a zip archive (checked: rhi.components.archives) whose ``modelDescription.xml`` names the
  generationTool ``rhi`` (the C body, every component's own description), or a pythonfmu FMU whose slave
  module is rhi's (``resources/slavemodule.txt`` names ``rhi_fmu_slave_*`` beside ``resources/rhi_component.txt``:
  a body; ``rhi_agent_slave_*`` or ``rhi_agent_slave3_*`` (FMI 3.0) beside ``resources/rhi_agent.json``: an
  agent);
- ``.ssp``: a zip archive whose ``SystemStructure.ssd`` names the generationTool ``rhi``;
- ``.csv``: run-system's table: the header ``time`` and then the connectors ``component.variable``, sorted,
  every row that follows in the first block a number per column, and rhi's mark: the extended attribute
  ``user.rhi.sha256`` that run-system sets to the sha256 of the bytes it wrote (:func:`mark`), still matching
  them (a CSV of the user's of the same shape, or rhi's edited since, is not rhi's; on a file system that
  keeps no extended attributes, the shape alone, as before the mark).
"""
from __future__ import annotations

import csv
import errno
import hashlib
import io
import os
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

MAX_MEMBER_BYTES = 16 * 2**20   # a model or system description read to be identified
MAX_CSV_HEAD_BYTES = 1 << 20    # the first block of a CSV read to be identified
SLAVES = {"rhi_fmu_slave_": "resources/rhi_component.txt", "rhi_agent_slave_": "resources/rhi_agent.json",
          "rhi_agent_slave3_": "resources/rhi_agent.json"}  # the FMI 3.0 agent's script (master/export/agent_fmu.py)


def _zip_member(path: Path, member: str) -> tuple[set[str], bytes | None] | str:
    """(the archive's member names, ``member``'s bytes or None if it has none), or what makes ``path`` not a sound
    zip archive."""
    from rhi.components.archives import ArchiveError, check_archive

    if not zipfile.is_zipfile(path):
        return "not a zip archive"
    try:
        check_archive(path)
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
            if member not in names:
                return names, None
            info = archive.getinfo(member)
            if info.file_size > MAX_MEMBER_BYTES:
                return f"its {member} is over {MAX_MEMBER_BYTES} bytes"
            return names, archive.read(info)
    except (ArchiveError, OSError, zipfile.BadZipFile, RuntimeError, ValueError) as error:
        return f"not a readable zip archive ({' '.join(str(error).split())[:120]})"


def _generation_tool(data: bytes) -> str | None:
    try:
        return ET.fromstring(data).get("generationTool")
    except ET.ParseError:
        return None


def fmu_problem(path: str | os.PathLike) -> str | None:
    """None if ``path`` is an FMU rhi exported (module notes), else what it is not."""
    found = _zip_member(Path(path), "modelDescription.xml")
    if isinstance(found, str):
        return found
    names, description = found
    if description is None:
        return "no modelDescription.xml"
    if _generation_tool(description) == "rhi":
        return None
    slave = _zip_member(Path(path), "resources/slavemodule.txt")
    module = slave[1] if not isinstance(slave, str) and slave[1] is not None and len(slave[1]) < 256 else b""
    module = module.decode("utf-8", "replace").strip()
    if any(module.startswith(prefix) and marker in names for prefix, marker in SLAVES.items()):
        return None
    return "its model description names another generationTool than rhi and its slave is not rhi's"


def ssp_problem(path: str | os.PathLike) -> str | None:
    """None if ``path`` is an SSP package rhi exported (module notes), else what it is not."""
    from rhi.master.export.ssp_package import SSD

    found = _zip_member(Path(path), SSD)
    if isinstance(found, str):
        return found
    if found[1] is None:
        return f"no {SSD}"
    if _generation_tool(found[1]) != "rhi":
        return f"its {SSD} names another generationTool than rhi"
    return None


def csv_problem(path: str | os.PathLike) -> str | None:
    """None if ``path`` is a table rhi run-system wrote (module notes), else what it is not."""
    try:
        with open(path, "rb") as file:
            head = file.read(MAX_CSV_HEAD_BYTES)
    except OSError as error:
        return f"unreadable ({error.strerror or error})"
    complete = head if len(head) < MAX_CSV_HEAD_BYTES else head[:head.rfind(b"\n") + 1]
    try:
        rows = list(csv.reader(io.StringIO(complete.decode("utf-8"))))
    except (UnicodeDecodeError, csv.Error):
        return "not a UTF-8 CSV file"
    if not rows:
        return "no header"
    header, *rows = rows
    connectors = header[1:]
    if header[:1] != ["time"] or connectors != sorted(connectors) or \
            not all(name.count(".") >= 1 and not name.startswith(".") for name in connectors):
        return "its header is not rhi run-system's (time, then the connectors component.variable, sorted)"
    for row in rows:
        if len(row) != len(header) or not all(_number(cell) for cell in row):
            return "a row is not a number per column"
    if not marked(path):
        return f"it does not carry rhi's mark of the table it wrote, {MARK}, or its bytes changed since"
    return None


MARK = "user.rhi.sha256"  # the extended attribute rhi run-system sets on the CSV it writes: the sha256 of its bytes


def mark(path: str | os.PathLike, data: bytes) -> None:
    """Set rhi's mark on the file ``path`` holding ``data`` (nothing where the file system keeps no attributes)."""
    try:
        os.setxattr(path, MARK, hashlib.sha256(data).hexdigest().encode("ascii"), follow_symlinks=False)
    except (OSError, AttributeError):
        pass


def marked(path: str | os.PathLike) -> bool:
    """Whether ``path`` carries rhi's mark and its bytes still hash to it."""
    try:
        expected = os.getxattr(path, MARK, follow_symlinks=False).decode("ascii")
    except OSError as error:  # a file system that keeps no attributes: its shape alone, as before the mark
        return error.errno in (errno.ENOTSUP, errno.EOPNOTSUPP)
    except (AttributeError, UnicodeDecodeError):
        return False
    try:
        with open(path, "rb") as file:
            hasher = hashlib.sha256()
            for block in iter(lambda: file.read(1 << 20), b""):
                hasher.update(block)
    except OSError:
        return False
    return hasher.hexdigest() == expected


def _number(text: str) -> bool:
    try:
        float(text)  # repr of a float: nan and inf too
    except ValueError:
        return False
    return True
