"""The connections of a system, resolved once into per-component input setters.

Gauss-Seidel: each component reads the newest outputs (those of the components before it in the
same step). Jacobi: every component reads a snapshot of the outputs as they were at t.

Example::

    links = Links(system)
    snapshot = links.snapshot()          # Jacobi only
    for inputs in links.inputs:          # one Inputs per component, in step order
        inputs.set(snapshot)             # or inputs.set() for Gauss-Seidel
"""
from __future__ import annotations

from rhi.master.cosim.system import System, split


class Inputs:
    """The connected inputs of one component.

    Verbs: :meth:`set` (copy each connected source output into its input).

    Attributes
    ----------
    component : Component
        The component whose inputs are set.
    feeds : list of tuple
        ``(input name, source component, source output name, snapshot key)`` per connected input.
    """

    __slots__ = ("component", "feeds")

    def __init__(self, component, feeds: list[tuple]):
        self.component = component
        self.feeds = feeds

    def set(self, snapshot: dict | None = None) -> None:
        """Set every connected input of the component from its source output.

        Parameters
        ----------
        snapshot : dict or None
            None (Gauss-Seidel, and initialization): read each source's current value; a source that has
            no value yet (at initialization, one later in the order) leaves the input at its start value.
            A dict from :meth:`Links.snapshot` (Jacobi): read the outputs as they were when it was taken.
        """
        component = self.component
        if snapshot is None:
            for target, source, output, _ in self.feeds:
                value = source.values.get(output)
                if value is not None:
                    component.set(target, value)
        else:
            for target, _, _, key in self.feeds:
                component.set(target, snapshot[key])


class Links:
    """Every connection of a system, resolved once before the run.

    Verbs: :attr:`inputs` (one :class:`Inputs` per component, in step order), :meth:`snapshot`.

    Parameters
    ----------
    system : System
        A validated system; its component order is the Gauss-Seidel order.
    """

    def __init__(self, system: System):
        feeds = {name: [] for name in system.components}
        sources = {}
        for target, source in system.feeds().items():
            (target_name, target_var), (source_name, source_var) = split(target), split(source)
            key = (source_name, source_var)
            sources[key] = system.components[source_name]
            feeds[target_name].append((target_var, sources[key], source_var, key))
        self.inputs = [Inputs(component, feeds[name]) for name, component in system.components.items()]
        self._sources = [(key, component, key[1]) for key, component in sources.items()]

    def snapshot(self) -> dict:
        """The current value of every connected output, by reference (outputs are replaced, never mutated).

        Returns
        -------
        dict
            ``(component name, output name) -> array`` of shape (B, *shape), for :meth:`Inputs.set`.
        """
        return {key: source.values[output] for key, source, output in self._sources}
