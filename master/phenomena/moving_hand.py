"""`rhi phenomenon moving-hand`: the moving rubber hand beside the human references.

The real arm (free) swings by itself at the shoulder; the rubber arm, the only arm in view, repeats the
movement after a delay; no touch. The paper's brain perceives (its action is not fed to the body: the movement
is the participant's own, and the released agent's illusion task ran without action); its gamma weighs the
delay between the seen and the felt turning points of the movement by eqs. 8-9
(:mod:`rhi.components.brain.turning_points`). Drift and gamma are the means over the last movement period.
The task (its protocol, system, measures and table): :mod:`rhi.master.tasks.moving_hand`; here, its figure beside
the human references.
"""
from __future__ import annotations

from rhi.master import models
from rhi.master.tasks import moving_hand as task
from rhi.master.tasks.base import TaskResult

NAME = task.NAME
HUMAN_TABLE = "moving_hand"  # its human references in human.toml


class MovingHand(task.MovingHand):
    """The moving-hand task with its figure beside the human references (moving_hand.png)."""

    def figures(self, result: TaskResult, folder) -> list[str]:
        """moving_hand.png: drift and gamma relative to 0 s against the delay, beside the human references."""
        from rhi.master.outputs.figures import save
        save(figure(result.config, self.found(result)), folder / "moving_hand.png")
        return ["moving_hand.png"]


def figure(config: dict, found: dict[str, dict]):
    """moving_hand.png's ``Figure``: drift and gamma relative to 0 s against the delay, a line per decoder, with
    the human references."""
    from rhi.master.outputs.figures import subplots
    from rhi.master.phenomena.report import caption, draw_human, human_references

    delays = config["moving_hand"]["delays"]
    references = human_references(HUMAN_TABLE)
    fig, axes = subplots(1, 2, figsize=(10, 5.4))
    for axis, key, label in ((axes[0], "drift_cm", "drift toward the rubber hand, relative to 0 s"),
                             (axes[1], "gamma", "gamma (common cause), relative to 0 s")):
        for kind, values in found.items():
            zero = values[key][delays.index(0.0)] if 0.0 in delays else 1.0
            axis.plot(delays, values[key] / zero, "o-", label=f"{models.of(config).name} model, {kind}")
        axis.axhline(0.5, color="gray", ls=":", lw=1, label="half the 0 s value")
        axis.set_xlim(-0.05, max(delays) + 0.05)
        draw_human(axis, references, with_labels=axis is axes[0])
        axis.set_xlabel("visuomotor delay (s)")
        axis.set_ylabel(label)
        axis.legend(fontsize="x-small")
    fig.suptitle("rhi phenomenon moving-hand: the rubber arm repeats the real arm's movement after a delay",
                 fontsize=10)
    fig.text(0.01, 0.005, caption(references, models.of(config).name), fontsize=6, va="bottom", wrap=True)
    fig.tight_layout(rect=(0, 0.2, 1, 0.95))  # room for the caption
    return fig
