"""One source per default: a built-in model's settings are the source of its brain's parameter values, and the
brain declares each as its start value.

For every registered built-in model, the configuration that runs it (defaults.toml with the model's settings file
merged over it) is read at every plain parameter source of its brain (``"table.key"``) and compared with the start
value the brain declares for that parameter (the same value and type). Every key of the model's own settings must
reach the model: as a plain source of a brain parameter, as a key a derived parameter is computed from
(``batchable``), as the pose encoder key, or as the trials per point of a phenomenon. tests/test_defaults.py does
the same for the task's components and the paper's brain over defaults.toml.
"""
import pytest

from rhi.components.variables import Variable
from rhi.master import config as configuration
from rhi.master import models
from rhi.master.models.base import config_key
from rhi.master.models.causal import CausalModel

KINDS = ("conv", "vae")  # the decoder slots a pose encoder key is formatted with


def same(a, b) -> bool:
    """Equal and of the same type (1 is not 1.0, True is not 1)."""
    return type(a) is type(b) and a == b


def value_at(config: dict, key: str):
    table, _, name = key.partition(".")
    return config[table][name]


def wrong_starts(model, config: dict) -> list[str]:
    """Each plain source whose configured value is not the start its brain parameter declares."""
    declared = {f"brain.{v.name}": v.start for v in model.brain().variables.values() if v.causality == "parameter"}
    wrong = []
    for path, source in model.parameter_sources.items():
        key = config_key(source)
        if key is None:
            continue  # derived or per trial: no configured default to hold the start to
        value, start = value_at(config, key), declared[path]
        if not same(value, start):
            wrong.append(f"{key} = {value!r} ({type(value).__name__}) but {path} starts at {start!r} "
                         f"({type(start).__name__})")
    return wrong


def used_for_trials_per_point(model, config: dict, key: str) -> bool:
    """Whether ``trials_per_point`` reads ``key``: it answers a changed value with that value (an int key only)."""
    value = value_at(config, key)
    if type(value) is not int:
        return False
    changed = configuration.merge(config, configuration.nest({key: value + 1}))
    return model.trials_per_point(changed) == value + 1


def loose_keys(model, config: dict) -> list[str]:
    """The keys of the model's settings that no brain parameter, derived parameter, pose encoder or trial count
    reads."""
    plain = {config_key(source) for source in model.parameter_sources.values()} - {None}
    encoders = {model.pose_encoder_key.format(kind=kind) for kind in KINDS} if model.pose_encoder_key else set()
    reached = plain | set(model.batchable) | encoders
    given = {f"{table}.{key}" for table, keys in model.settings().items() if table != "model" for key in keys}
    return sorted(key for key in given - reached if not used_for_trials_per_point(model, config, key))


@pytest.mark.parametrize("name", sorted(models.BUILT_IN))
def test_the_brain_starts_at_the_values_its_settings_give(name):
    wrong = wrong_starts(models.get(name), configuration.load(model_name=name))
    assert not wrong, f"model {name}: " + "; ".join(wrong)


@pytest.mark.parametrize("name", sorted(models.BUILT_IN))
def test_every_key_of_a_model_s_settings_reaches_the_model(name):
    model, config = models.get(name), configuration.load(model_name=name)
    assert all(key.partition(".")[2] in config.get(key.partition(".")[0], {}) for key in model.batchable)
    loose = loose_keys(model, config)
    assert not loose, f"model {name}: settings that nothing of the model reads: {loose}"


class OffStart(CausalModel):
    """The causal model with its brain's timing noise declared at twice its settings' value, and a key of its own
    that nothing reads."""

    own_settings = {"causal": {"unread": 1.5}}

    def brain(self):
        made = super().brain()
        given = made.variables["timing_noise_sd"]
        made.variables["timing_noise_sd"] = Variable(given.name, given.causality, start=2 * given.start,
                                                     unit=given.unit, min=given.min)
        return made


def test_a_start_off_its_settings_and_a_key_nothing_reads_are_each_reported():
    model, config = OffStart(), configuration.load(model_name="causal")
    config["causal"]["unread"] = 1.5  # as the settings would give it (the configuration refuses an unknown key)
    assert [line.split(" = ")[0] for line in wrong_starts(model, config)] == ["causal.timing_noise_sd"]
    assert loose_keys(model, config) == ["causal.unread"]
