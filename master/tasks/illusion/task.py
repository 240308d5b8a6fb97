"""The rubber-hand illusion as a registered task (:class:`rhi.master.tasks.base.Task`): the paper's protocol, its
system (:mod:`rhi.master.tasks.illusion.wiring`), its run (:mod:`rhi.master.tasks.illusion.publish`: failures
isolated, the decoders' batches side by side) and the hooks an agent FMU and an SSP package of it need
(one parameter file per trial of the protocol, ``conv_left_sync_0``)."""
from __future__ import annotations

import copy

import numpy as np

from rhi.master import config as configuration
from rhi.master import models
from rhi.master.config import bodies
from rhi.master.config.protocol import Trial, make_trial, plan
from rhi.master.config.sources import parameters
from rhi.master.cosim import ConfigError
from rhi.master.tasks.agent_ports import SEED, SEED_HIGH, SEED_LOW, body_links, exposed, split_seed
from rhi.master.tasks.base import Task
from rhi.master.tasks.illusion import wiring
from rhi.master.tasks.illusion.measures import measures


class Illusion(Task):
    """The paper's protocol: the hidden arm held, the rubber arm seen and touched, in time or late.

    ``body``: an FMU or a body variant to use as the body (None: the native pymunk plant), :meth:`with_body`.
    """

    name = "illusion"
    summary = "the paper's protocol: the hidden arm held, the rubber arm seen and touched, in time or late"
    command = "rhi experiment"
    body = None
    own_settings: dict = {}  # a task built on this one: its new tables, and keys it changes (examples/my_task.py)
    # the FMI export hooks
    agent, model_name = "rhi.master.export.agent:Agent", "RubberHandAgent"  # the component; the FMI model identifier
    system_name, system_description = "RubberHandIllusion", "the rubber-hand agent and a body"
    trial_form = "CONDITION/STIMULATION/INDEX, e.g. left/sync/0"

    def with_body(self, body: str | None) -> "Illusion":
        """This task with ``body`` (an FMU, a body variant's name, or None: the native plant) as the body."""
        task = copy.copy(self)
        task.body = body
        return task

    def load(self, path=None, overrides: dict | None = None, quick: bool = False, model_name: str = "paper") -> dict:
        """The experiment's configuration (:func:`rhi.master.config.load`), with :attr:`own_settings` over it (its new
        tables added, its keys of existing ones merged), then the file and ``overrides``."""
        if not self.own_settings:
            return configuration.load(path, overrides or {}, quick=quick, model_name=model_name)
        base, own = configuration.load(None, {}, quick=quick, model_name=model_name), copy.deepcopy(self.own_settings)
        config = configuration.merge({**base, **{table: values for table, values in own.items() if table not in base}},
                                     {table: values for table, values in own.items() if table in base})
        if path is not None:
            config = configuration.merge(config, configuration.read_toml(path))
        config = configuration.merge(config, configuration.nest(overrides or {}))
        configuration.validate(config)
        return config

    def plan(self, config: dict) -> list[Trial]:
        """The protocol's trials (:func:`rhi.master.config.protocol.plan`)."""
        return plan(config)

    def scenario(self, config: dict, kind: str, trials=(), checkpoint: str | None = None):
        """The rubber-hand system of decoder ``kind`` (:func:`rhi.master.tasks.illusion.wiring.scenario`), the
        configuration's body (``experiment.body``)."""
        from rhi.master.decoders.cache import checkpoint_path, decoder_component
        from rhi.master.runtime.pool import JOB_THREADS
        from rhi.master.tasks.illusion.runner import body_factory

        path, make_body = checkpoint or checkpoint_path(kind, config, must_exist=True), body_factory(None, config)[0]
        return wiring.scenario(decoder_component(kind, path, config, threads=JOB_THREADS), config,
                               make_body() if make_body else None, trials)

    def parameters(self, trials: list, config: dict, system) -> dict:
        """The trials' parameters that the system declares
        (:func:`rhi.master.tasks.illusion.wiring.system_parameters`)."""
        return wiring.system_parameters(trials, config, system)

    def measures(self, result, config: dict, trials: list) -> dict:
        """Drift, force, gamma and the others per step (:func:`rhi.master.tasks.illusion.measures.measures`)."""
        return measures(result, models.of(config))

    def outcome(self, config: dict, trial: Trial) -> dict:
        """One trial alone (a sweep's trial of this task): its end-of-trial values, ``{name: float}`` (drift_cm,
        force_n, gamma_final, and every other measure's), through :meth:`scenario`, :meth:`parameters` and
        :meth:`measures`."""
        from rhi.master.tasks.illusion.measures import end_of_trial
        from rhi.master.tasks.scene import run as run_scenario

        result = run_scenario(self.scenario(config, trial.decoder, [trial]), config,
                              lambda system: self.parameters([trial], config, system), 1, trials=[trial])
        final = end_of_trial(result.times, self.measures(result, config, [trial]),
                             config["experiment"]["probe_times"])
        renamed = {"force_x_n": "force_n", "gamma": "gamma_final"}
        return {renamed.get(key, key): float(np.asarray(values)[0]) for key, values in final.items()}

    def check_before_work(self, config: dict, context) -> None:
        """The decoders' checkpoints or training settings, the model's pose encoders, the body FMU."""
        from rhi.master.tasks.illusion.publish import checked_before_work
        checked_before_work(config, self.body, context.device)

    def simulate(self, config: dict, context, workers=None):
        """The protocol in lockstep batches, failures isolated (:func:`rhi.master.tasks.illusion.publish.simulate_protocol`)."""
        from rhi.master.runtime.pool import Workers
        from rhi.master.tasks.illusion.publish import simulate_protocol
        from rhi.master.tasks.illusion.runner import body_factory

        body = self.body if self.body is not None else bodies.configured(config)  # --body, else experiment.body
        declared = body_factory(body, config)[1]  # checked already (check_before_work)
        if workers is None:
            with Workers(1 if context.device != "cpu" else context.processes) as own:
                return simulate_protocol(config, body, context, own, declared, self)
        return simulate_protocol(config, body, context, workers, declared, self)

    def tables(self, result) -> dict:
        """summary.csv, trials.csv (and participants.csv for a population that varies)."""
        from rhi.master.tasks.illusion.publish import table_texts
        return table_texts(result)

    def figures(self, result, folder) -> list[str]:
        """figures/: the panels, the Jacobian images, a trial's animation (a cohort's strips)."""
        from rhi.master.tasks.illusion.publish import write_figures
        return write_figures(result, folder, None)

    # -- the FMI export hooks ---------------------------------------------------------------------------------
    def trials(self, config: dict, kind: str) -> list[Trial]:
        """The protocol's trials of decoder ``kind``, in the protocol's order."""
        return [t for t in plan(config) if t.decoder == kind]

    def trial_name(self, trial: Trial) -> str:
        """``conv_left_sync_0``: a trial's parameter file, without folder and suffix."""
        return f"{trial.decoder}_{trial.condition}_{trial.stimulation}_{trial.index}"

    def parse_trial(self, text: str, config: dict, kind: str) -> Trial:
        """``left/sync/0`` -> the protocol's trial of decoder ``kind`` (ConfigError naming what is unknown)."""
        parts = text.split("/")
        if len(parts) != 3 or not parts[2].isdigit():
            raise ConfigError(f"--trial {text!r} must be {self.trial_form}")
        condition, stimulation, index = parts[0], parts[1], int(parts[2])
        for table, value in (("conditions", condition), ("stimulations", stimulation)):
            if value not in config[table]:
                raise ConfigError(f"--trial {text!r}: no {table[:-1]} {value!r} (have: {', '.join(config[table])})")
        return make_trial(config, kind, condition, stimulation, index)

    def links(self, config: dict) -> list[tuple[str, str]]:
        """The body's links: the experiment's (``wiring.CONNECTIONS``)."""
        return body_links()

    def agent_values(self, trial: Trial, config: dict, declared: dict, starts: dict) -> dict:
        """The agent FMU's parameters for ``trial``, ``{name: (type, value)}`` (:func:`agent_parameters`; ``starts``
        unused)."""
        return agent_parameters(trial, config, declared)


def agent_parameters(trial: Trial, config: dict, declared: dict) -> dict:
    """The agent FMU's parameters for ``trial``: ``{name: (type, value)}`` from :func:`rhi.master.config.sources.parameters`
    (the experiment's own values), the seed split into two Integers."""
    given = parameters([trial], config)
    values = {}
    for path, value in given.items():
        name = path.partition(".")[2]
        if path == SEED:
            low, high = split_seed(int(value[0]))
            values[SEED_LOW], values[SEED_HIGH] = ("Integer", low), ("Integer", high)
        elif exposed(path, config) and declared.get(name, ("",))[0] == "parameter":
            values[name] = (declared[name][1], np.asarray(value).reshape(-1)[0])
    return values
