"""Any FMI 2.0 co-simulation FMU imported as a native component, on top of fmpy (the other way, a component exported
as an FMU: :mod:`..fmi_export`).

Modules: :mod:`contract` (a file checked against a contract before it loads), :mod:`library` (unzipped
once, its library held), :mod:`watchdog` (time limits and signals during calls), :mod:`adapter`
(:class:`FMUComponent`).
"""
from .adapter import FMUComponent
from .contract import check_contract
from .library import extracted, guard_library

__all__ = ["FMUComponent", "check_contract", "extracted", "guard_library"]
