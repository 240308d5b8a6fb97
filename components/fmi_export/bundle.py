"""Importing from an FMU's own copy of its packages: :func:`bundled`, for the body FMUs' slave scripts
(``components/body/fmu_slave.py``, FMI 2.0; ``components/body/fmu_slave3.py``, FMI 3.0).

A script runs this file by its path from the copy of ``components`` beside it (the copy cannot be imported by
name before this file is there to do it) and calls :func:`for_script`, the bootstrap both scripts share. It
imports nothing of the project, so the FMU's copy and the host's are the same file.

Example (a slave script's first lines)::

    BUNDLE = globals().get("BUNDLE") or runpy.run_path(
        os.path.join(HERE, "components", "fmi_export", "bundle.py"))["for_script"](__name__)
    Base = BUNDLE.bundled(HERE, "components.fmi_export.slave_fmi2:ComponentSlaveBase", __name__)
"""
from __future__ import annotations

import importlib
import importlib.util
import os
import sys

# The builders' runtimes, which they put in an FMU's resources too: the host's copy is the one to use.
RUNTIMES = {"pythonfmu", "pythonfmu3"}

_BUNDLES: dict[str, tuple[set, dict]] = {}  # resources folder -> (its packages, the modules imported from them)


def for_script(script: str):
    """This file as a module of the slave script ``script`` (its module name), loaded by its path once per process
    under a name of that script's, ``<script>_bundle``: pythonfmu's builder reloads the script, and its library runs
    it again from the module a process imported first, whose folder (a builder's staging folder) may be gone by
    then; the module loaded first, with its record of what it imported (:func:`bundled`), is the one they get."""
    name = f"{script}_bundle"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, __file__)
        sys.modules[name] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(sys.modules[name])
    return sys.modules[name]


def bundled(resources: str, spec: str, script: str):
    """``module:name`` from the FMU's own copy of its packages (a class, say).

    In a process that already imported this checkout's ``components`` (the master, under
    fmpy in-process), a plain import would return the host's modules. The packages in
    ``resources`` are imported with the host's modules of the same names set aside, and
    put back afterwards, so the FMU runs the code it carries and the host keeps its own.
    A folder is listed once: pythonfmu runs the script again from the module a process
    imported first, whose folder (a builder's staging folder) may be gone by then.
    ``script``: the slave script's module name, which is in ``resources`` but not one of its packages.
    """
    if resources not in _BUNDLES:
        own = {entry.removesuffix(".py") for entry in os.listdir(resources)
               if entry.endswith(".py") or os.path.isfile(os.path.join(resources, entry, "__init__.py"))}
        _BUNDLES[resources] = own - {script} - RUNTIMES, {}
    own, bundle = _BUNDLES[resources]
    ours = lambda module: module.partition(".")[0] in own
    host = {name: module for name, module in sys.modules.items() if ours(name)}
    for name in host:
        del sys.modules[name]
    sys.modules.update(bundle)
    sys.path.insert(0, resources)
    try:
        module, _, name = spec.partition(":")
        return getattr(importlib.import_module(module), name)
    finally:
        sys.path.remove(resources)
        bundle.update({name: module for name, module in sys.modules.items() if ours(name)})
        for name in bundle:
            sys.modules.pop(name, None)
        sys.modules.update(host)


COMPONENT_FILE = "rhi_component.txt"  # "<model name> <module>:<class>", in a body FMU's resources


def served_component(resources: str, script: str):
    """(model name, component, description) of the body FMU whose resources are ``resources``: the class its
    ``rhi_component.txt`` names, from the FMU's own copy (:func:`bundled`), instantiated; the description is the
    first line of the class's docstring, else its spec."""
    with open(os.path.join(resources, COMPONENT_FILE)) as file:
        model_name, spec = file.read().split()
    component = bundled(resources, spec, script)()
    doc = (type(component).__doc__ or "").strip()
    return model_name, component, doc.splitlines()[0] if doc else spec

