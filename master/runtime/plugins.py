"""A plug-in named by a spec: ``package.module:Class`` or ``path/to/file.py:Class``, loaded once per process.

The one loader of the model registry (:mod:`rhi.master.models`) and the task registry (:mod:`rhi.master.tasks`):
whatever goes wrong in a user's file (missing, raising, no such class, a class whose ``__init__`` raises) is one
ConfigError line naming the spec, never a traceback.
"""
from __future__ import annotations

import hashlib
import importlib
import importlib.util
import sys
from pathlib import Path

from rhi.master.cosim import ConfigError


def load_object(spec: str, what: str):
    """The object ``spec`` names, instantiated when it is a class; ``what`` (``"model"``, ``"task"``) starts every
    error's line."""
    where, _, attribute = spec.rpartition(":")
    if not where or not attribute.isidentifier():
        raise ConfigError(f"{what} {spec!r}: give path/to/file.py:Class or package.module:Class")
    module = _file_module(spec, where, what) if where.endswith(".py") else _package_module(spec, where, what)
    found = getattr(module, attribute, None)
    if found is None:
        raise ConfigError(f"{what} {spec!r}: {where} has no {attribute}")
    try:
        return found() if isinstance(found, type) else found
    except (Exception, SystemExit) as error:  # noqa: BLE001: a user's class; its __init__ never ends rhi
        raise ConfigError(f"{what} {spec!r}: {attribute}() raised {type(error).__name__}: {error}") from None


def _file_module(spec: str, where: str, what: str):
    path = Path(where)
    if not path.is_file():
        raise ConfigError(f"{what} {spec!r}: no file {path}")
    # one module per file, whatever names it: a file holding a model and a task is imported once
    module_name = f"rhi_user_model_{hashlib.sha256(str(path.resolve()).encode()).hexdigest()[:16]}"
    module = sys.modules.get(module_name)
    if module is None:
        loader = importlib.util.spec_from_file_location(module_name, path)
        module = importlib.util.module_from_spec(loader)
        sys.modules[module_name] = module  # dataclasses and pickling look the module up by name
        try:
            loader.loader.exec_module(module)
        except (Exception, SystemExit) as error:  # noqa: BLE001: a user's file; say what went wrong in one line
            del sys.modules[module_name]
            raise ConfigError(f"{what} {spec!r}: {type(error).__name__}: {error}") from None
    return module


def _package_module(spec: str, where: str, what: str):
    try:
        return importlib.import_module(where)
    except ImportError as error:
        raise ConfigError(f"{what} {spec!r}: cannot import {where}: {error}") from None
    except (Exception, SystemExit) as error:  # noqa: BLE001: a plug-in's module; it never ends rhi
        raise ConfigError(f"{what} {spec!r}: importing {where} raised {type(error).__name__}: {error}") from None
