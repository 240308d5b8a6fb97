"""Configuration: shipped defaults, user TOML, overrides; bad keys and values named."""
import pytest

from rhi.master import config
from rhi.master.cosim import ConfigError


def test_defaults_are_the_paper_protocol():
    loaded = config.load()
    experiment = loaded["experiment"]
    assert (experiment["trials"], experiment["steps"], experiment["step_size"]) == (5, 1500, 0.02)
    assert loaded["brain"]["gamma0"] == 0.01 and loaded["brain"]["decay_rate"] == 1 / 80
    assert loaded["conditions"] == {"left": -0.15, "center": 0.0, "right": 0.15}
    assert loaded["stimulations"]["async"] == {"delay_min": 0.0, "delay_max": 1.0, "touch": True, "blocks": []}


def test_file_and_overrides_apply_in_order(tmp_path):
    path = tmp_path / "my.toml"
    path.write_text("[experiment]\ntrials = 3\nseed = 7\n[brain]\ngamma0 = 0.05\n")
    loaded = config.load(path, {"experiment.trials": 2}, quick=True)
    assert loaded["experiment"]["trials"] == 2 and loaded["experiment"]["seed"] == 7
    assert loaded["experiment"]["steps"] == 300  # from [quick]
    assert loaded["brain"]["gamma0"] == 0.05


def test_unknown_key_is_named_with_the_closest(tmp_path):
    path = tmp_path / "typo.toml"
    path.write_text("[brain]\ngama0 = 0.1\n")
    with pytest.raises(ConfigError, match=r"unknown config key brain\.gama0 \(did you mean brain\.gamma0\?\)"):
        config.load(path)
    with pytest.raises(ConfigError, match=r"unknown config key expriment \(did you mean experiment\?\)"):
        config.load(overrides={"expriment.trials": 1})


def test_one_unknown_key_message_for_configs_and_sweeps():
    assert str(config.unknown_key("brain.gama0", ["gamma0", "sync_sd"])) == \
        "unknown config key brain.gama0 (did you mean brain.gamma0?)"
    assert str(config.unknown_key("expriment", ["experiment", "brain"])) == \
        "unknown config key expriment (did you mean experiment?)"
    assert str(config.unknown_key("sweep.trails", ["trials", "quick"], "sweep")) == \
        "unknown sweep key sweep.trails (did you mean sweep.trials?)"
    assert str(config.unknown_key("brain.zzz", ["gamma0"])) == "unknown config key brain.zzz"


def test_new_conditions_may_be_added(tmp_path):
    path = tmp_path / "far.toml"
    path.write_text("[experiment]\nconditions = ['far']\n[conditions]\nfar = -0.3\n")
    assert config.load(path)["conditions"]["far"] == -0.3


@pytest.mark.parametrize("text, message", [
    ("[experiment]\ntrials = 0\n", r"experiment\.trials must be at least 1, got 0"),
    ("[experiment]\ntrials = 'five'\n", r"experiment\.trials = 'five' must be a int"),
    ("[brain]\ngamma0 = 1.5\n", r"brain\.gamma0 must be in \(0, 1\], got 1\.5"),
    ("[stimulations.sync]\ndelay_min = -0.1\n", r"stimulations\.sync: need 0 <= delay_min <= delay_max"),
    ("[experiment]\nconditions = ['up']\n", r"experiment\.conditions: 'up' is not defined in \[conditions\]"),
    ("[experiment]\ndecoders = ['gan']\n", r"experiment\.decoders: unknown decoder 'gan'"),
    ("[decoder]\nvisual_variance = -1.0\n", r"decoder\.visual_variance must be at least 1e-12"),
    ("[camera]\nblur = -0.01\n", r"camera\.blur must be >= 0 m, got -0\.01"),
    ("experiment = 3\n", r"config key experiment must be a table"),
])
def test_bad_values_are_named(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        config.load(path)


def test_unreadable_files(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        config.load(tmp_path / "missing.toml")
    broken = tmp_path / "broken.toml"
    broken.write_text("[experiment\n")
    with pytest.raises(ConfigError, match="cannot be read"):
        config.load(broken)


def test_typos_inside_open_tables_are_named(tmp_path):
    path = tmp_path / "typo.toml"
    path.write_text("[stimulations.sync]\ndely_max = 0.2\n")
    with pytest.raises(ConfigError, match=r"unknown config key stimulations\.sync\.dely_max \(did you mean "
                                          r"stimulations\.sync\.delay_max\?\)"):
        config.load(path)
    path.write_text("[stimulations.slow]\ndelay_min = 0.5\ndelay_mx = 0.6\n")
    with pytest.raises(ConfigError, match=r"unknown config key stimulations\.slow\.delay_mx"):
        config.load(path)
    path.write_text("[experiment]\nstimulations = ['slow']\n[stimulations.slow]\ndelay_min = 0.5\ndelay_max = 0.6\n")
    assert config.load(path)["stimulations"]["slow"] == {"delay_min": 0.5, "delay_max": 0.6, "touch": True,
                                                         "blocks": []}


def test_shipped_train_defaults_are_the_training_code_defaults():
    from rhi.components.vision.training import TrainSettings

    defaults = TrainSettings().as_dict()
    defaults.pop("resolution")  # taken from experiment.resolution
    assert config.load()["train"] == defaults
