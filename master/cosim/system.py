"""A system: components plus connections (output -> input), validated before it runs."""
from __future__ import annotations

from dataclasses import dataclass

from rhi.components.component import Component
from rhi.master.cosim.errors import ConfigError

SCHEMES = ("jacobi", "gauss-seidel")


@dataclass(frozen=True)
class Connection:
    """One link: the ``source`` output feeds the ``target`` input.

    Attributes
    ----------
    source, target : str
        ``component.variable`` paths.
    """

    source: str
    target: str

    def __str__(self):
        return f"{self.source} -> {self.target}"


def split(path: str) -> tuple[str, str]:
    """``"component.variable"`` -> ``("component", "variable")``; ConfigError if it is not of that form."""
    component, dot, variable = path.partition(".")
    if not dot or not component or not variable:
        raise ConfigError(f"{path!r} is not of the form component.variable")
    return component, variable


class System:
    """Components and the connections between them.

    Verbs: :meth:`validate`, :meth:`variable`, :meth:`feeds`, :meth:`algebraic_loop`.

    Example::

        system = System([source, integrator], [("source.y", "integrator.u")])

    Parameters
    ----------
    components : list of Component
        In Gauss-Seidel order: each component reads the newest outputs of those before it in the
        same step, and the previous step's outputs of those after it. Names must be unique.
    connections : iterable
        ``(source, target)`` pairs of ``component.variable`` paths, or :class:`Connection` objects.
    """

    def __init__(self, components: list[Component], connections):
        self.components = {}
        for component in components:
            if component.name in self.components:
                raise ConfigError(f"two components are named {component.name!r}")
            self.components[component.name] = component
        self.connections = [c if isinstance(c, Connection) else Connection(*c) for c in connections]

    def variable(self, path: str):
        """The declared variable at ``path``.

        Parameters
        ----------
        path : str
            ``component.variable``.

        Returns
        -------
        Variable
            Its declaration; ConfigError naming the component or variable if there is none.
        """
        name, variable = split(path)
        if name not in self.components:
            raise ConfigError(f"{path}: no component named {name!r} (have: {', '.join(self.components)})")
        component = self.components[name]
        if variable not in component.variables:
            raise ConfigError(f"{path}: component {name!r} has no variable {variable!r}")
        return component.variables[variable]

    def feeds(self) -> dict[str, str]:
        """The connections as a mapping.

        Returns
        -------
        dict
            Target input path -> source output path, in connection order.
        """
        return {c.target: c.source for c in self.connections}

    def validate(self, scheme: str = "gauss-seidel") -> None:
        """Check the system before it runs.

        Parameters
        ----------
        scheme : str
            ``"gauss-seidel"`` (algebraic loops are errors) or ``"jacobi"``.

        Raises
        ------
        ConfigError
            Listing every problem found, each naming its variable or connection: unknown names,
            causality, type, shape or unit mismatches, an input fed twice, an unconnected input
            without a start value, an algebraic loop.
        """
        if scheme not in SCHEMES:
            raise ConfigError(f"scheme {scheme!r} is not one of {', '.join(SCHEMES)}")
        problems = []
        fed: dict[str, Connection] = {}
        for connection in self.connections:
            try:
                source, target = self.variable(connection.source), self.variable(connection.target)
            except ConfigError as error:
                problems.append(f"connection {connection}: {error}")
                continue
            if source.causality != "output":
                problems.append(f"connection {connection}: source {connection.source} is an "
                                f"{source.causality}, not an output")
            if target.causality != "input":
                problems.append(f"connection {connection}: target {connection.target} is an "
                                f"{target.causality}, not an input")
            if (source.type, source.shape, source.element) != (target.type, target.shape, target.element):
                problems.append(f"connection {connection}: type mismatch, {source.kind} feeds {target.kind}")
            if source.unit != target.unit:
                problems.append(f"connection {connection}: unit mismatch, {source.unit or 'none'} feeds "
                                f"{target.unit or 'none'}")
            if connection.target in fed:
                problems.append(f"input {connection.target} is fed twice: by {fed[connection.target].source} "
                                f"and by {connection.source}")
            fed[connection.target] = connection
        for name, component in self.components.items():
            for variable in component.variables.values():
                path = f"{name}.{variable.name}"
                if variable.causality == "input" and variable.start is None and path not in fed:
                    problems.append(f"input {path} is not connected and has no start value")
        if scheme == "gauss-seidel" and not problems:
            loop = self.algebraic_loop()
            if loop:
                problems.append("algebraic loop (every link is direct feedthrough): " + " -> ".join(loop))
        if problems:
            raise ConfigError("; ".join(problems))

    def algebraic_loop(self) -> list[str] | None:
        """A cycle of variables in which every link is direct, or None.

        Edges: each connection (output -> input) and, inside a component, each
        input -> output it feeds through directly (``Variable.depends_on``).

        Returns
        -------
        list of str or None
            The cycle as paths, first and last the same; None if there is none.
        """
        edges: dict[str, list[str]] = {}
        for connection in self.connections:
            edges.setdefault(connection.source, []).append(connection.target)
        for name, component in self.components.items():
            inputs = [v.name for v in component.variables.values() if v.causality == "input"]
            for output in (v for v in component.variables.values() if v.causality == "output"):
                for source in inputs if output.depends_on is None else output.depends_on:
                    edges.setdefault(f"{name}.{source}", []).append(f"{name}.{output.name}")
        # Depth-first search with colours; the grey stack is the current path.
        colour, path = {}, []

        def visit(node):
            colour[node] = "grey"
            path.append(node)
            for successor in edges.get(node, ()):
                if colour.get(successor) == "grey":
                    return path[path.index(successor):] + [successor]
                if successor not in colour:
                    found = visit(successor)
                    if found:
                        return found
            path.pop()
            colour[node] = "black"
            return None

        for node in list(edges):
            if node not in colour:
                found = visit(node)
                if found:
                    return found
        return None
