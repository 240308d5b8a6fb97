"""Recording outputs: a copy of each recorded value after initialization and after every step."""
from __future__ import annotations

import numpy as np

from rhi.master.cosim.system import System, split


class Recorder:
    """Copies of the recorded outputs, one row per tick.

    Verbs: :meth:`record` (after initialization, then after every step), :meth:`arrays`.

    Parameters
    ----------
    system : System
        The system whose outputs are recorded.
    paths : list of str
        ``component.variable`` paths of outputs (or locals), already checked.
    """

    def __init__(self, system: System, paths):
        self._columns = [(path, system.components[split(path)[0]], split(path)[1], []) for path in paths]

    def record(self) -> None:
        """Append a copy of every recorded value (components replace their outputs, but a copy is safe)."""
        for _, component, variable, rows in self._columns:
            rows.append(np.array(component.values[variable], copy=True))

    def arrays(self) -> dict[str, np.ndarray]:
        """The recording so far.

        Returns
        -------
        dict
            ``path -> array`` of shape (rows, B, *shape): row 0 the initial values, row n those after step n.
        """
        return {path: np.stack(rows) for path, _, _, rows in self._columns}
