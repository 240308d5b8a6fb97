"""Writing an FMU file: the target checked first, the file built beside it and renamed into place, and
pythonfmu's builder run on a slave script (the body's pythonfmu FMUs, the agent FMU, the C body's zip)."""
from __future__ import annotations

import hashlib
import shutil
import sys
import tempfile
from pathlib import Path

from rhi.master.cosim import ConfigError
from rhi.master.outputs.atomic import umask
from rhi.master.outputs.out_file import check_output_file, place_file


def check_target(out) -> Path:
    """FILE.fmu as a Path if an FMU can be written there (checked before anything is built)."""
    return check_output_file(out, "FMU file", ".fmu")


def built_beside(out: Path, build) -> Path:
    """``build(target)`` writes a file at ``target`` (and returns its path), in a folder beside ``out``; the file
    is then renamed into place: ``out`` is whole, the old one, or absent, whatever happens. An error of
    writing that names no file (a full disk under a builder's zipfile) is raised naming ``out``.

    Parameters
    ----------
    out : Path
        The file to write (checked already: :func:`check_target`).
    build : callable
        ``build(target) -> Path``.

    Returns
    -------
    Path
        ``out``.
    """
    try:
        beside = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}.", suffix=".partial"))
    except OSError as error:
        raise ConfigError(f"cannot write into {out.parent}: {error.strerror or error}") from None
    try:
        built = Path(build(beside / out.name))
        built.chmod(0o666 & ~umask())
        place_file(built, out)  # never over a file that appeared at out meanwhile
    except OSError as error:
        if error.filename is None and error.errno is not None:  # a builder's write (zipfile's) names no file
            raise OSError(error.errno, error.strerror, str(out)) from error
        raise
    finally:
        shutil.rmtree(beside, ignore_errors=True)
    return out


def staged_script(slave: Path, staging: Path, prefix: str, loads=()) -> Path:
    """A copy of the slave script ``slave`` in ``staging``, named ``<prefix>_<hash>.py`` after its content and
    that of the files it ``loads`` when imported: in one process, FMUs whose slave code differs never share
    a module (a process imports a module of one name once)."""
    source = slave.read_bytes()
    digest = hashlib.sha1(source)
    for path in loads:
        digest.update(Path(path).read_bytes())
    script = staging / f"{prefix}_{digest.hexdigest()[:10]}.py"
    script.write_bytes(source)
    return script


def build_with_pythonfmu(script: Path, target: Path, project_files, what: str, fmi: str = "2.0") -> Path:
    """pythonfmu's builder (FMI 2.0; pythonfmu3's for ``fmi`` 3.0): the FMU of ``script`` with ``project_files`` in
    its resources, at ``target``.

    A slave the builder cannot load is refused as ``cannot build <what>: <reason>`` (ConfigError);
    ``sys.path`` is left as it was (the builder puts the script's folder on it for good).
    """
    if fmi == "3.0":
        from pythonfmu3.builder import FmuBuilder
    else:
        from pythonfmu.builder import FmuBuilder

    saved_path = list(sys.path)
    try:
        return Path(FmuBuilder.build_FMU(script, dest=target, project_files=list(project_files)))
    except (ImportError, AttributeError, ValueError) as error:
        raise ConfigError(f"cannot build {what}: {error}") from None
    finally:
        sys.path[:] = saved_path
