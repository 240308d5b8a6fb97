"""Saving results: a tidy CSV of the recorded outputs and a JSON file of provenance.

Every file is written atomically (to a temporary file in the same folder, then
renamed), so a crash leaves either the old file or the new one, never half of one.
"""
from __future__ import annotations

import csv
import io
import json
import os
import platform
import shutil
import sys
import tempfile
from importlib import metadata
from pathlib import Path

import numpy as np

from master.cosim import ConfigError

PACKAGES = ("numpy", "scipy", "torch", "pymunk", "pillow", "fmpy", "pythonfmu", "matplotlib", "dask", "rhi")
UMASK = os.umask(0o022)
os.umask(UMASK)  # read once: the umask can only be read by setting it
MAX_CSV_ELEMENTS = 64  # per-trial elements of one variable; images do not belong in a CSV


def atomic_write(path: str | os.PathLike, data: str | bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file and a rename."""
    path = Path(path)
    mode = "wb" if isinstance(data, bytes) else "w"
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(handle, mode, **({} if mode == "wb" else {"newline": "", "encoding": "utf-8"})) as file:
            file.write(data)
        os.chmod(temporary, 0o666 & ~UMASK)  # mkstemp makes files private; results are ordinary files
        os.replace(temporary, path)
    except BaseException:
        os.unlink(temporary)
        raise


def package_versions() -> dict[str, str]:
    versions = {"python": sys.version.split()[0], "platform": platform.platform()}
    for package in PACKAGES:
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            pass
    return versions


def csv_columns(path: str, per_trial_shape: tuple[int, ...]) -> list[str]:
    """Column names of one variable: ``path`` for a scalar, ``path[i]`` (``path[i,j]``) for arrays."""
    if not per_trial_shape:
        return [path]
    return [f"{path}[{','.join(map(str, index))}]" for index in np.ndindex(*per_trial_shape)]


def result_csv(result) -> str:
    """The recorded outputs as a tidy CSV: one row per step and trial."""
    header, blocks = ["time", "trial"], []
    for path, values in result.values.items():
        per_trial = values.shape[2:]
        if int(np.prod(per_trial)) > MAX_CSV_ELEMENTS:
            raise ConfigError(f"cannot write {path} to CSV: {per_trial} per trial is more than "
                              f"{MAX_CSV_ELEMENTS} values (record it in memory instead)")
        header += csv_columns(path, per_trial)
        blocks.append(values.reshape(values.shape[0], values.shape[1], -1).astype(float))
    steps, trials = len(result.times), result.batch_size
    table = np.concatenate([np.broadcast_to(result.times[:, None, None], (steps, trials, 1)),
                            np.broadcast_to(np.arange(trials)[None, :, None], (steps, trials, 1)),
                            *blocks], axis=2).reshape(steps * trials, -1)
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(header)
    for row in table:
        writer.writerow([repr(float(row[0])), int(row[1]), *(repr(float(x)) for x in row[2:])])
    return buffer.getvalue()


def save(result, directory: str | os.PathLike, configuration: dict, seeds: dict | list | None = None,
         name: str = "results") -> tuple[Path, Path]:
    """Write ``NAME.csv`` and ``NAME.json`` into ``directory``; returns both paths."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    table = result_csv(result)  # fails before anything is written
    provenance = {"configuration": configuration, "seeds": seeds, "versions": package_versions(),
                  "scheme": result.scheme, "step_size": result.step_size, "batch_size": result.batch_size,
                  "steps": len(result.times) - 1, "timings": result.timings}
    csv_path, json_path = directory / f"{name}.csv", directory / f"{name}.json"
    atomic_write(csv_path, table)
    atomic_write(json_path, json.dumps(provenance, indent=2, sort_keys=True, default=str) + "\n")
    return csv_path, json_path


def staging_folder(out: str | os.PathLike, force: bool) -> Path:
    """Check DIR can be written and return an empty staging folder beside it."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"output {out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise ConfigError(f"output folder {out} exists and is not empty (use --force to replace it)")
    parent = out.absolute().parent
    if not parent.is_dir():
        raise ConfigError(f"cannot write {out}: folder {parent} does not exist")
    try:
        staging = Path(tempfile.mkdtemp(dir=parent, prefix=f".{out.name}.", suffix=".partial"))
    except OSError as error:
        raise ConfigError(f"cannot write into {parent}: {error.strerror}") from None
    staging.chmod(0o777 & ~UMASK)  # mkdtemp makes it private; the published folder is an ordinary one
    return staging


def publish(staging: Path, out: str | os.PathLike) -> None:
    """Replace DIR by the finished staging folder."""
    out = Path(out)
    if out.exists():
        shutil.rmtree(out)
    os.replace(staging, out)
