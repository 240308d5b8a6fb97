"""A Dask worker preload (distributed's ``dask_setup`` hook) for the local pool: each worker process dies
with the rhi process that started it, even when that is SIGKILLed (docs/safety.md, Processes).

The local pool's nannies run inside rhi and spawn the workers from a thread that lives as long as the
worker; rhi's pid reaches the worker in the dask configuration the nanny hands it (``PARENT_KEY``).
"""
from __future__ import annotations

PARENT_KEY = "rhi.sweep-pid"  # dask configuration: the pid of the rhi process whose pool this worker is


def dask_setup(worker) -> None:
    """Dask's preload hook, run in each new worker: the worker process dies with the rhi process whose pool it is."""
    import dask

    from rhi.master.outputs.processes import die_with_parent

    parent = dask.config.get(PARENT_KEY, None)
    die_with_parent(int(parent) if parent is not None else None)
