"""The FMI co-simulation calls both slave bases make on a component, with a failure logged as one line.

:mod:`rhi.components.fmi_export.slave_fmi2` (pythonfmu, FMI 2.0) and :mod:`rhi.components.fmi_export.slave_fmi3` (pythonfmu3, FMI 3.0)
differ in their status enums and packages, not in what a call does to the component (one trial of
:mod:`rhi.components.component`): each passes its ``log`` and its error status. Imports no pythonfmu package, so
either base can use it (the body FMUs carry it in their copy of ``components``).
"""
from __future__ import annotations

import traceback


def exit_initialization(component, log, error_status) -> None:
    """fmiExitInitializationMode: ``component`` initializes; a failure is logged as one line and raised.

    Parameters
    ----------
    component : rhi.components.component.Component
        One trial.
    log : callable
        The slave's ``log(message, status)``.
    error_status
        Its FMI version's error status.
    """
    try:
        component.exit_initialization_mode()
        if component.last_reason:
            raise RuntimeError(component.last_reason)
    except Exception as error:  # the reason as one line in the log (pythonfmu's own is the exception's repr)
        log(str(error), error_status)
        raise


def step(component, current_time: float, step_size: float, log, error_status) -> bool:
    """fmiDoStep: one step of ``component``; False when it failed (an exception, or a status of discard or
    worse), its reason logged as one line.

    Parameters
    ----------
    component : rhi.components.component.Component
        One trial.
    current_time, step_size : float
        The step's start and size, s.
    log, error_status
        As for :func:`exit_initialization`.

    Returns
    -------
    bool
    """
    try:
        status = component.do_step(current_time, step_size)
    except Exception as error:  # raised, pythonfmu says "unknown error" and pythonfmu3 fmi3Fatal: log the cause
        log("".join(traceback.format_exception_only(error)).strip(), error_status)
        return False
    if status >= 2:  # discard, error or fatal
        log(component.last_reason or f"status {status}", error_status)
        return False
    return True
