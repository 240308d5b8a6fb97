"""The agent (stimulus, rubber arm, camera, decoder, brain, wired as in the experiment) as ONE component.

:class:`Agent` is a component whose inside is the experiment's system without its body
(:func:`rhi.master.tasks.illusion.wiring.build_system`, every connection that does not touch the body), run
by a :class:`rhi.master.cosim.Session` one communication step per :meth:`Agent.step`. Its ports are
scalars, so that it can be an FMI 2.0 FMU (``master/export/agent_fmu.py``):

- inputs: what the body feeds the inside (the sensed joint angles, and the felt hand that only the
  spatial extension reads), one port per body output, named as the body contract and the brain name it;
- outputs: what the brain feeds the body (the action), then :data:`OBSERVED` (mu, gamma, the event
  times, ...) and the perceived hand (forward kinematics of mu, the drift's first term);
- parameters: every scalar parameter of the inner components that the experiment sets per trial or
  from ``defaults.toml`` (:func:`parameter_paths`), named as the component names it, with the
  configuration's value as start; the 63-bit stimulus seed is two FMI Integers (:func:`split_seed`).

Units, ranges and descriptions come from the inner components' declared variables: one source of
truth. With the body after the agent, Gauss-Seidel, ``System([agent, body])`` is the experiment's
system, step for step (tests/test_agent.py checks it bitwise). A task of its own is a subclass that
chooses the whole system (:meth:`Agent.whole_system`), the parameters and how they reach the inside
(:class:`rhi.master.export.reach_agent.ReachAgent`, the free arm reaching to a seen goal).

Example::

    agent = Agent("conv.pt", "conv", config.load())
    system = System([agent, ArmPlant()], agent.connections())
"""
from __future__ import annotations

import numpy as np

from rhi.components.body import kinematics
from rhi.components.component import Component, ComponentError, StepFailure
from rhi.components.variables import Variable
from rhi.master.cosim import SimulationError, Session, System
from rhi.master.tasks.illusion import wiring
from rhi.master.config.protocol import make_trial
from rhi.master.config import sources as parameter_sources
from rhi.master.config.sources import sources
from rhi.master.tasks.agent_ports import (BODY, FIXED_AT_BUILD, SEED, SEED_HIGH, SEED_LOW, body_links,  # noqa: F401
                                          exposed, split_seed, touches_body)

# FMI name, inner path, element of an Array (None: a scalar): outputs beyond the action.
OBSERVED = (
    ("mu_shoulder", "brain.mu", 0),
    ("mu_elbow", "brain.mu", 1),
    ("gamma", "brain.gamma", None),
    ("free_energy", "brain.free_energy", None),
    ("action_rate_shoulder", "brain.action_rate", 0),
    ("action_rate_elbow", "brain.action_rate", 1),
    ("visual_time", "stimulus.visual_time", None),
    ("tactile_time", "stimulus.tactile_time", None),
    ("visual_error", "decoder.visual_error", None),
    ("ball_x", "stimulus.ball", 0),
    ("ball_y", "stimulus.ball", 1),
)
JOINTS = ("shoulder", "elbow")
AXES = ("x", "y")
PERCEIVED = ("perceived_hand_x", "perceived_hand_y")


def join_seed(low, high) -> np.ndarray:
    """The seed of :func:`split_seed`'s two Integers: ``high * 2^32 + (low mod 2^32)``, per trial (int64)."""
    low, high = np.asarray(low, dtype=np.int64), np.asarray(high, dtype=np.int64)
    return (high << 32) | (low & 0xFFFFFFFF)


def without_body(whole: System) -> System:
    """``whole`` less its body: the other components in order, the connections among them."""
    return System([c for name, c in whole.components.items() if name != BODY],
                  [c for c in whole.connections if not touches_body(c)])


def agent_connections(agent: str = "agent", body: str = BODY, links=None) -> list[tuple[str, str]]:
    """The connections of the two-component system agent + body: each of :func:`body_links` (of ``links``,
    default the experiment's) with the inner end renamed to the agent's port, each once: a body output
    feeds the agent's input of its name (which feeds every inner input it fed), an agent output of the
    inner source's name feeds the body's input."""
    connections = []
    for source, target in body_links(links):
        (source_name, source_var), (_, target_var) = source.split("."), target.split(".")
        link = ((f"{body}.{source_var}", f"{agent}.{source_var}") if source_name == BODY
                else (f"{agent}.{source_var}", f"{body}.{target_var}"))
        if link not in connections:
            connections.append(link)
    return connections


def parameter_paths(system: System, config: dict) -> list[str]:
    """The inner parameters that are the agent's parameters: every scalar one the experiment sets
    (:data:`rhi.master.config.sources.PARAMETER_SOURCES`) but those fixed when the agent is built (constructor arguments,
    the blur the decoder was trained on) and the derived ones (the brain's start belief, the rest pose)."""
    return [f"{name}.{variable.name}" for name, component in system.components.items()
            for variable in component.variables.values()
            if variable.causality == "parameter" and variable.type != "Array"
            and exposed(f"{name}.{variable.name}", config)]


def configured(path: str, variable: Variable, config: dict):
    """The start of an agent parameter: the configuration's value for a plain key, else the variable's own."""
    key = parameter_sources.config_key(sources(config)[path])
    if key is None:
        return variable.start
    table, name = key.split(".")
    return config[table][name]


class Agent(Component):
    """The rubber-hand agent (stimulus, rubber arm, camera, decoder, brain) as one component with scalar ports.

    Parameters
    ----------
    checkpoint : str
        The decoder's checkpoint file.
    kind : str
        ``conv`` or ``vae``: the decoder's kind (checked against the checkpoint).
    config : dict
        A loaded configuration (``rhi.master.config.load``): the resolution, the camera's blur,
        the decoder's mode, and the start values of the parameters.
    name : str
        The component's name.
    """

    task = "illusion"
    summary = "the rubber-hand agent (stimulus, rubber arm, camera, {kind} decoder at {resolution} px, brain)"
    observed = OBSERVED  # (FMI name, inner path, element or None[, the description, {} the inner one's])
    perceived = "drift = perceived_hand_x - the real hand's x"

    def __init__(self, checkpoint: str, kind: str, config: dict, name: str = "agent"):
        self.checkpoint, self.kind, self.config = checkpoint, kind, config
        whole = self.whole_system()
        # A terminated component cannot start again: each inner session gets new components (the decoder's
        # model is loaded once per process, decoders.loaded).
        self._build = lambda: without_body(self.whole_system())
        self._system = without_body(whole)
        self.links = body_links(whole.connections)
        self.inputs = {}  # port -> the inner inputs the body output of its name feeds
        for source, target in self.links:
            if source.startswith(BODY + "."):
                self.inputs.setdefault(source.split(".")[1], []).append(target)
        self.actions = {source.split(".")[1]: source for source, target in self.links if target.startswith(BODY + ".")}
        self.parameters = {path.split(".")[1]: path for path in parameter_paths(self._system, self.config)}
        super().__init__(name, self._declare())
        self._session = None
        self._used = None  # the parameter values the session was built with

    def whole_system(self) -> System:
        """The task's whole system, its body included, with new components: here the experiment's."""
        from rhi.master.decoders.cache import decoder_component  # torch only when an agent is built

        return wiring.build_system(decoder_component(self.kind, self.checkpoint, self.config), self.config)

    def connections(self, body: str = BODY) -> list[tuple[str, str]]:
        """The connections of ``System([self, body])``: :func:`agent_connections` of this agent's links."""
        return agent_connections(self.name, body, self.links)

    def _inner(self, path: str) -> Variable:
        return self._system.variable(path)

    def inner_variable(self, path: str) -> Variable:
        """The inner system's declared variable ``path`` (``camera.image``)."""
        return self._inner(path)

    def inner(self, path: str):
        """The inner session's current value of ``path`` (batch first), or None before the session is built."""
        return None if self._session is None else self._session.get(path)

    def parameter_variables(self) -> list[Variable]:
        """The agent's parameters, declared as the inner variables they set are (the seed as two Integers)."""
        variables = []
        for name, path in self.parameters.items():
            inner = self._inner(path)
            if path == SEED:
                low = Variable(SEED_LOW, "parameter", "Integer", start=0, unit=inner.unit, min=-2 ** 31, max=2 ** 31 - 1,
                               description="stimulus seed, its low 32 bits read as a signed 32-bit integer (any value; "
                                           "a small seed is itself)")
                high = Variable(SEED_HIGH, "parameter", "Integer", start=0, unit=inner.unit, min=0, max=2 ** 31 - 1,
                                description="stimulus seed, its bits above the low 32 (seed = seed_high * 2^32 + "
                                            "(seed mod 2^32))")
                variables += [low, high]
                continue
            variables.append(Variable(name, "parameter", inner.type, start=configured(path, inner, self.config),
                                      unit=inner.unit, min=inner.min, max=inner.max, description=inner.description))
        return variables

    def _declare(self) -> list[Variable]:
        variables = self.parameter_variables()
        for name, paths in self.inputs.items():  # declared as the brain declares it, if the brain reads it
            inner = self._inner(next((p for p in paths if p.startswith("brain.")), paths[0]))
            variables.append(Variable(name, "input", inner.type, start=inner.start, unit=inner.unit,
                                      description=inner.description))
        for name, path in self.actions.items():
            inner = self._inner(path)
            variables.append(Variable(name, "output", inner.type, start=None, unit=inner.unit, min=inner.min,
                                      max=inner.max, description=inner.description, depends_on=()))
        for name, path, element, *template in self.observed:
            inner = self._inner(path)
            label = "" if element is None else f" [{(JOINTS if inner.unit.startswith('deg') else AXES)[element]}]"
            description = (template[0] if template else "{}").format(inner.description) + label
            variables.append(Variable(name, "output", start=None, unit=inner.unit, min=inner.min, max=inner.max,
                                      description=description, depends_on=()))
        for axis, name in zip(AXES, PERCEIVED):
            variables.append(Variable(name, "output", start=None, unit="m", depends_on=(),
                                      description=f"{axis} of the perceived hand, the forward kinematics of mu "
                                                  f"({self.perceived})"))
        return variables

    # -- the inner session ----------------------------------------------------------------------
    def inner_parameters(self) -> dict:
        """The inner system's parameters for this agent's current values: the experiment's
        (:func:`rhi.master.config.sources.parameters`) for what the agent does not expose, the agent's own for the rest."""
        trial = make_trial(self.config, self.kind, self.config["experiment"]["conditions"][0],
                           self.config["experiment"]["stimulations"][0], 0)
        given = {path: value for path, value in parameter_sources.parameters([trial], self.config).items()
                 if path.partition(".")[0] in self._system.components and path not in parameter_sources.CONSTRUCTED}
        for name, path in self.parameters.items():
            given[path] = join_seed(self.values[SEED_LOW], self.values[SEED_HIGH]) if path == SEED else self.values[name]
        return given

    def _parameter_values(self) -> dict:
        return {v.name: self.values[v.name].copy() for v in self.variables.values() if v.causality == "parameter"}

    def _start(self) -> None:
        """(Re)build the inner session from the current parameters, unless it is built from these already."""
        used = self._parameter_values()
        if self._session is not None:
            if all(np.array_equal(used[k], self._used[k]) for k in used):
                return
            self._session.close()
        if self._used is not None:  # its components ran (or failed to start): a terminated one cannot start again
            self._system = self._build()
        self._session, self._used = None, used
        try:
            self._session = Session(self._system, self.start_time, self.stop_time, "gauss-seidel", self.batch_size,
                                    self.inner_parameters())
        except SimulationError as error:
            raise StepFailure(str(error), trials=error.trials) from None
        self._publish()

    def publish_initial(self):
        """Build the inner session (the FMI initialization of the five components) and publish its outputs,
        readable in initialization mode. A failure is reported when initialization ends, where masters look
        (:meth:`initialize` starts again, and fails again)."""
        try:
            self._start()
        except (StepFailure, ComponentError):
            pass

    def initialize(self):
        """As :meth:`publish_initial`, again only if a parameter changed in initialization mode."""
        self._start()  # again after a failed start: the parameters may have been mended since

    def step(self, t, h):
        """Set the body's inputs inside, step the inner session from ``t`` by ``h`` (s) and publish its outputs."""
        session = self._session
        for name, paths in self.inputs.items():
            for path in paths:
                session.set(path, self.values[name])
        try:
            session.step(h, start=t)
        except SimulationError as error:
            raise StepFailure(str(error), trials=error.trials) from None
        self._publish()

    def _publish(self) -> None:
        get = self._session.get
        for name, path in self.actions.items():
            self.values[name] = np.array(get(path), copy=True)
        for name, path, element, *_ in self.observed:
            value = get(path)
            self.values[name] = np.array(value if element is None else value[:, element], copy=True)
        mu = get("brain.mu")
        x, y = kinematics.forward(mu[:, 0], mu[:, 1])
        self.values[PERCEIVED[0]], self.values[PERCEIVED[1]] = np.asarray(x, float), np.asarray(y, float)

    def terminate_hook(self):
        """Close the inner session, if one was built."""
        if self._session is not None:
            self._session.close()
