"""The default decoders the package ships: what `rhi train` makes from the defaults, found before any training,
and their fast-mode verdicts found before any check."""
import json
import os
import subprocess
import sys

import pytest

from rhi.components.vision import checkpoint
from rhi.master import config as configuration
from rhi.master.tasks.illusion import fast_check
from rhi.master.decoders.cache import SHIPPED, check_decoders, checkpoint_path
from rhi.master.decoders.training import load_decoder, train_settings
from tests.conftest import ROOT


@pytest.fixture
def empty_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("RHI_CACHE", str(tmp_path))
    return tmp_path


def test_the_defaults_use_the_shipped_decoders_and_their_shipped_verdicts(empty_cache):
    config = configuration.load()
    check_decoders(config)  # nothing to train: nothing asked of the (empty) cache
    checkpoints = {kind: checkpoint_path(kind, config, must_exist=True) for kind in config["experiment"]["decoders"]}
    assert {os.path.dirname(path) for path in checkpoints.values()} == {str(SHIPPED)}
    for kind, path in checkpoints.items():
        metadata = load_decoder(path, config["experiment"]["resolution"]).metadata  # fits today's camera
        assert metadata["kind"] == kind and metadata["settings"] == train_settings(config).identity()
    verdicts = fast_check.verdicts(config, checkpoints)  # found, not run: the cache stays empty
    assert list(empty_cache.iterdir()) == []
    assert all(verdict["fast"] and verdict["relative_error"] <= fast_check.DRIFT_BOUND for verdict in verdicts.values())
    # Nothing else is shipped: every file is one of these checkpoints or verdicts.
    names = {os.path.basename(path) for path in checkpoints.values()}
    names |= {f"fast-check-{kind}-{fast_check.verdict_key(path, config)}.json" for kind, path in checkpoints.items()}
    # and the causal model's pose encoders (it reads no pixel term by default: no fast-mode verdict of its own)
    names |= {f"pose-{kind}-r{config['experiment']['resolution']}.pt" for kind in checkpoints}
    # and the ownership model's own pose encoders, over the rubber arm's whole reach
    names |= {f"pose-ownership-{kind}-r{config['experiment']['resolution']}.pt" for kind in checkpoints}
    assert {path.name for path in SHIPPED.iterdir()} == names


def test_rhi_train_makes_the_checkpoint_the_experiment_trains_side_by_side(quick_cache, tmp_path, monkeypatch):
    """The shipped checkpoints' property at the --quick size: `rhi train` from the same settings gives the bytes
    the experiment's side-by-side training wrote into the cache."""
    config = configuration.load(quick=True)
    settings = train_settings(config)
    given = tmp_path / "quick.toml"
    given.write_text(f"[experiment]\nresolution = {settings.resolution}\n[train]\n" + "".join(
        f"{key} = {json.dumps(getattr(settings, key))}\n" for key in configuration.load(quick=True)["train"]))
    monkeypatch.setenv("RHI_CACHE", str(quick_cache))  # its training set is rendered there already
    for kind in ("conv", "vae"):
        out = tmp_path / f"{kind}.pt"
        done = subprocess.run([sys.executable, "-m", "rhi", "train", "--decoder", kind, "--config", str(given),
                               "--out", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-2000:]
        assert out.read_bytes() == open(checkpoint_path(kind, config, must_exist=True), "rb").read()
        assert "seconds" not in checkpoint.load(out)[1]  # no wall time in the bytes
