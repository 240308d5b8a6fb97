"""What an agent FMU of a task exposes of its system: the body's links, the parameters set from the configuration,
the stimulus seed as two FMI Integers. The tasks' export hooks (:mod:`rhi.master.tasks.base`) and the exporter
(:mod:`rhi.master.export.agent`) read them here.
"""
from __future__ import annotations

from rhi.components.component import ComponentError
from rhi.master.config import sources as parameter_sources
from rhi.master.config.sources import sources
from rhi.master.cosim import Connection

BODY = "body"  # the experiment's name for the body component
SEED = "stimulus.seed"
SEED_LOW, SEED_HIGH = "seed", "seed_high"  # its two FMI Integers: the low 32 bits (signed), the high 31
# Structural, or fixed by the decoder bundled with the agent: given when the agent is built, not ports.
FIXED_AT_BUILD = ("camera.blur",  # the decoder was trained on images of this blur (its checkpoint is checked)
                  # the schedule (docs/configuration.md, "Stimulation schedules"): the configuration's, its first
                  # condition's and stimulation's, so that the agent's ports stay those of earlier builds
                  "stimulus.stroke_duration", "stimulus.touch", "stimulus.blocks", "stimulus.hidden",
                  "stimulus.arm_in_view", "camera.arm_visible")

def split_seed(seed: int) -> tuple[int, int]:
    """A seed in [0, 2^63) as two FMI 2.0 Integers (32-bit, signed).

    Parameters
    ----------
    seed : int
        The stimulus's seed (the protocol's per-trial seeds use 63 bits).

    Returns
    -------
    (low, high) : tuple of int
        ``low``: the low 32 bits, read as a signed 32-bit integer; ``high``: the bits above, in [0, 2^31).
    """
    seed = int(seed)
    if not 0 <= seed < 2 ** 63:
        raise ComponentError(f"seed {seed} is outside [0, 2^63)")
    low = seed & 0xFFFFFFFF
    return (low - 2 ** 32 if low >= 2 ** 31 else low), seed >> 32


def touches_body(connection) -> bool:
    """Whether a :class:`~rhi.master.cosim.Connection` has the body at either end."""
    return BODY in (connection.source.partition(".")[0], connection.target.partition(".")[0])


def body_links(connections=None) -> list[tuple[str, str]]:
    """The connections between the body and the rest: (source, target) paths, their order kept.

    Parameters
    ----------
    connections : iterable, optional
        ``(source, target)`` pairs or :class:`~rhi.master.cosim.Connection` objects of a whole system
        (default: the experiment's, ``wiring.CONNECTIONS``).
    """
    pairs = [(c.source, c.target) if isinstance(c, Connection) else tuple(c)
             for c in (experiment_links() if connections is None else connections)]
    return [(source, target) for source, target in pairs if touches_body(Connection(source, target))]


def exposed(path: str, config: dict) -> bool:
    """Whether parameter ``path`` (``component.variable``) is an agent parameter under ``config``: set from the
    configuration (the task's sources and the model's, :func:`rhi.master.config.sources.sources`), not the body's, not
    fixed when the agent is built, not derived."""
    source = sources(config).get(path)
    return (source is not None and not path.startswith(BODY + ".") and path not in parameter_sources.CONSTRUCTED
            and path not in FIXED_AT_BUILD and not source.startswith("derived:"))


def experiment_links() -> list:
    """The illusion's links (:data:`rhi.master.tasks.illusion.wiring.CONNECTIONS`)."""
    from rhi.master.tasks.illusion.wiring import CONNECTIONS
    return CONNECTIONS
