"""The paper's scale (`--preset paper`), at small sizes: the `--preset paper` configuration, the training settings it
uses (channels-last, fused Adam, stopping on the hand error), devices, caching, the paper network end to end
at 32 x 32, and the bench's protocol with trained decoders. CI never trains a paper-scale decoder."""
import argparse
import dataclasses
import hashlib
import json
import os
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from rhi.components.body import kinematics
from rhi.components.component import ComponentError
from rhi.components.vision import checkpoint
from rhi.components.vision.component import DEVICES, Decoder, GenerativeModel, resolve_device
from rhi.components.vision.fast import LinearisedDecoder
from rhi.components.vision.networks import build
from rhi.components.vision.training import LATER_FIELDS, TrainSettings, checkpoint_metadata, train
from rhi.master.bench import protocol as bench_protocol
from rhi.master.bench.settings import QUICK
from rhi.master.bench import training as training_bench
from rhi.master.commands import experiment as experiment_command
from rhi.master.commands.cli import build_parser, main
from rhi.master.cosim import ConfigError
from rhi.master import config as configuration
from rhi.master.decoders import training_data
from rhi.master.decoders.cache import checkpoint_path, ensure_checkpoints
from rhi.master.decoders.training import train_settings

ROOT = Path(__file__).resolve().parents[1]
# The TrainSettings fields a cached decoder's name was a hash of before the paper preset's keys existed.
EARLIER_FIELDS = ("samples", "epochs", "batch_size", "lr", "final_lr_fraction", "patience", "seed", "preset",
                  "resolution", "validation_fraction", "kl_weight", "prior_variance", "quality_poses", "threads")
# A small paper run: the paper preset and its networks, at 32 x 32 (start size 1 x 1), few samples and steps.
SMALL = {"experiment.resolution": 32, "experiment.trials": 1, "experiment.steps": 20, "train.samples": 96,
         "train.epochs": 2, "train.patience": 2, "train.quality_poses": 4, "train.threads": 1}


def write(path, text):
    path.write_text(text)
    return str(path)


def flatten(table, prefix=""):
    for key, value in table.items():
        if isinstance(value, dict):
            yield from flatten(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}", value


# -- the preset ---------------------------------------------------------------------------------------
def test_the_paper_preset_is_the_paper_s_scale_merged_over_the_defaults():
    with open(ROOT / "master" / "config" / "presets" / "paper_256.toml", "rb") as file:
        shipped = dict(flatten(tomllib.load(file)))
    paper, default = (dict(flatten(configuration.load(preset_name=name))) for name in ("paper", None))
    # What the preset must be, written here: 256 px, the paper's networks, the fast mode, the CPU speed-ups.
    assert paper["experiment.resolution"] == 256 and paper["train.preset"] == "paper"
    assert paper["decoder.fast"] is True and paper["train.channels_last"] is True
    assert paper["train.stop_hand_error_cm"] > 0
    # Every key it sets is a key of the defaults (merged like [quick]), and every other key is the default's.
    assert set(shipped) <= set(default)
    for key, value in paper.items():
        assert value == shipped.get(key, default[key]), key
    # ... and a key it sets only where it differs from the default (one source of truth).
    assert all(shipped[key] != default[key] for key in shipped), [k for k in shipped if shipped[k] == default[k]]
    # A user's file and the command line still go over it.
    assert configuration.load(preset_name="paper", overrides={"experiment.resolution": 64})["experiment"][
        "resolution"] == 64
    assert train_settings(configuration.load(preset_name="paper")).resolution == 256


def test_an_unknown_preset_and_quick_with_a_preset_are_refused(tmp_path, capsys):
    with pytest.raises(ConfigError, match="preset 'huge' is unknown; choose one of paper"):
        configuration.load(preset_name="huge")
    for argv in (["experiment", "--quick", "--preset", "paper", "--out", str(tmp_path / "x")],
                 ["experiment", "--preset", "huge", "--out", str(tmp_path / "x")],
                 ["train", "--decoder", "conv", "--preset", "huge", "--out", str(tmp_path / "c.pt")]):
        with pytest.raises(SystemExit) as exit_:
            main(argv)
        assert exit_.value.code == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and "--preset" in err, err
    assert not (tmp_path / "x").exists()


# -- training settings --------------------------------------------------------------------------------
def test_new_settings_at_their_defaults_leave_a_cached_decoder_s_name_and_metadata_as_they_were(tmp_path,
                                                                                               monkeypatch):
    monkeypatch.setenv("RHI_CACHE", str(tmp_path))
    config = configuration.load()
    earlier = {key: value for key, value in train_settings(config).as_dict().items() if key in EARLIER_FIELDS}
    assert set(earlier) == set(EARLIER_FIELDS)
    key = hashlib.sha256(json.dumps(["conv", earlier], sort_keys=True).encode()).hexdigest()[:16]
    assert os.path.basename(checkpoint_path("conv", config)) == f"conv-r64-default-{key}.pt"  # (the shipped one)
    assert checkpoint_path("conv", config, device="cpu") == checkpoint_path("conv", config)
    metadata = checkpoint_metadata("conv", train_settings(config), kinematics.REST_POSE, (40.0, 50.0), "h",
                                   {"validation_mse": 1.0, "validation_loss": 1.0, "seconds": 1.0, "best_epoch": 1,
                                    "epochs_run": 1, "history": []})
    assert metadata["settings"] == earlier and "device" not in metadata and "hand_error_checks_cm" not in metadata
    # Any of them set, or a GPU, names another decoder.
    others = {checkpoint_path("conv", config, device="cuda")} | {
        checkpoint_path("conv", configuration.load(overrides={f"train.{name}": value}))
        for name, value in (("channels_last", True), ("fused_adam", True), ("stop_hand_error_cm", 0.2))}
    assert len(others) == 4 and checkpoint_path("conv", config) not in others
    assert set(LATER_FIELDS) == set(TrainSettings.names()) - set(EARLIER_FIELDS)


@pytest.mark.parametrize("text, message", [("channels_last = 1", "train.channels_last = 1 must be a bool"),
                                           ("stop_hand_error_cm = -0.1", "stop_hand_error_cm = -0.1 must be a number"),
                                           ("fused_adam = 'yes'", "train.fused_adam = 'yes' must be a bool")])
def test_bad_new_settings_are_named(tmp_path, text, message):
    with pytest.raises(ConfigError, match=message):
        train_settings(configuration.load(write(tmp_path / "c.toml", f"[train]\n{text}\n")))
    with pytest.raises(ComponentError, match="fused_adam = 1 must be true or false"):  # without the config's check
        TrainSettings(fused_adam=1)


def test_the_encoder_pooled_before_its_relu_is_the_same_function_and_gradient():
    torch.manual_seed(0)
    model = build("vae", "tiny", 32)
    images = torch.rand(5, 32, 32, requires_grad=True)
    mean, log_variance = model.encoder(images)
    (mean.square().sum() + log_variance.sum()).backward()
    got = [images.grad.clone()] + [p.grad.clone() for p in model.encoder.parameters()]
    # The reference: every stage as conv -> ReLU -> 2x2 max-pool, written out with torch.nn.functional.
    for p in model.encoder.parameters():
        p.grad = None
    images.grad = None
    x = images[:, None]
    for conv in [m for m in model.encoder.convolutions if isinstance(m, torch.nn.Conv2d)]:
        x = F.max_pool2d(F.relu(F.conv2d(x, conv.weight, conv.bias, padding=1)), 2)
    out = model.encoder.dense(x)
    assert torch.equal(out[:, :2], mean) and torch.equal(out[:, 2:], log_variance)
    (out[:, :2].square().sum() + out[:, 2:].sum()).backward()
    want = [images.grad] + [p.grad for p in model.encoder.parameters()]
    assert all(torch.equal(a, b) for a, b in zip(got, want))


@pytest.fixture(scope="module")
def tiny_data():
    return training_data.generate(160, 16, seed=4)


def tiny_train(data, kind="conv", check=None, **settings):
    chosen = dict(preset="tiny", resolution=16, samples=160, batch_size=16, lr=1e-2, epochs=3, patience=3,
                  quality_poses=0, threads=1)
    chosen.update(settings)
    return train(kind, data.poses, data.images, data.rest_pose, data.half_ranges, TrainSettings(**chosen),
                 progress=False, check=check)


@pytest.mark.parametrize("kind", ["conv", "vae"])
def test_channels_last_and_fused_adam_train_the_same_decoder_up_to_rounding(tiny_data, kind):
    plain, plain_report = tiny_train(tiny_data, kind)
    fast, fast_report = tiny_train(tiny_data, kind, channels_last=True, fused_adam=True)
    # the weights come back contiguous, on the CPU, and close to the plain path's (Adam's rounding grows a little)
    for (name, a), b in zip(plain.state_dict().items(), fast.state_dict().values()):
        assert b.is_contiguous() and b.device.type == "cpu"
        assert torch.allclose(a, b, rtol=1e-3, atol=1e-4), name
    assert math.isclose(plain_report["validation_mse"], fast_report["validation_mse"], rel_tol=1e-3)
    # and the device "cpu" is the default path bit for bit
    again, _ = train(kind, tiny_data.poses, tiny_data.images, tiny_data.rest_pose, tiny_data.half_ranges,
                     TrainSettings(preset="tiny", resolution=16, samples=160, batch_size=16, lr=1e-2, epochs=3,
                                   patience=3, quality_poses=0, threads=1), progress=False, device="cpu")
    assert all(torch.equal(a, b) for a, b in zip(plain.state_dict().values(), again.state_dict().values()))


def test_training_stops_at_the_first_epoch_whose_hand_error_check_is_good_enough(tiny_data):
    errors = iter([0.9, 0.5, 0.29, 0.1, 0.05])
    seen = []

    def check(decoder):
        seen.append(decoder.training)
        return next(errors)

    _, report = tiny_train(tiny_data, epochs=5, patience=5, stop_hand_error_cm=0.3, check=check)
    assert report["epochs_run"] == 3 and [h["hand_error_cm"] for h in report["history"]] == [0.9, 0.5, 0.29]
    assert seen == [False] * 3  # checked in eval mode
    with pytest.raises(ComponentError, match="stop_hand_error_cm needs a check"):
        tiny_train(tiny_data, stop_hand_error_cm=0.3)


# -- devices --------------------------------------------------------------------------------------------
@pytest.mark.skipif(torch.cuda.is_available(), reason="a GPU is present: auto means cuda")
def test_auto_is_the_cpu_here_and_cuda_without_a_gpu_is_one_line_and_status_2(tmp_path, capsys):
    assert resolve_device("auto") == "cpu" and resolve_device("cpu") == "cpu"
    with pytest.raises(ComponentError, match="device cuda: torch .* sees no CUDA GPU here; use --device cpu"):
        resolve_device("cuda")
    with pytest.raises(ComponentError, match="device 'tpu' is unknown"):
        resolve_device("tpu")
    config = write(tmp_path / "t.toml", "[experiment]\nresolution = 16\n[train]\npreset = 'tiny'\nsamples = 40\n")
    for argv in (["train", "--decoder", "conv", "--config", config, "--device", "cuda", "--out",
                  str(tmp_path / "c.pt")],
                 ["experiment", "--quick", "--device", "cuda", "--out", str(tmp_path / "run")]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and "sees no CUDA GPU" in err, err
    assert not (tmp_path / "c.pt").exists() and not (tmp_path / "run").exists()
    assert not list(tmp_path.glob("decoder-data-*"))  # refused before any data were rendered


def test_the_command_line_offers_the_component_s_devices():
    parser = build_parser()
    for command in (["train", "--decoder", "conv", "--out", "c.pt"], ["experiment", "--out", "d"]):
        assert parser.parse_args(command).device == "auto"
        for device in DEVICES:
            assert parser.parse_args(command + ["--device", device]).device == device
    alone = argparse.ArgumentParser()
    experiment_command.add_device(alone)  # what both commands add
    assert tuple(next(a for a in alone._actions if a.dest == "device").choices) == DEVICES


def test_the_decoder_component_on_the_cpu_device_is_the_default_bit_for_bit():
    torch.manual_seed(2)
    model = GenerativeModel(build("conv", "tiny", 32).decoder, kinematics.REST_POSE, (40.0, 50.0))
    assert model.on("cpu") is model and model.device.type == "cpu"
    mu = np.array([kinematics.REST_POSE, [150.0, -95.0]])
    image = np.random.default_rng(0).random((2, 32, 32)).astype(np.float32)
    outputs = []
    for make in (lambda **d: Decoder(model, threads=1, **d), lambda **d: LinearisedDecoder(model, threads=1, **d)):
        for device in ({}, {"device": "cpu"}):
            decoder = make(**device)
            decoder.instantiate(2)
            decoder.set("mu", mu)
            decoder.set("image", image)
            decoder.initialize()
            outputs.append({k: np.array(decoder.values[k]) for k in ("visual_drive", "visual_error")})
    for a, b in ((outputs[0], outputs[1]), (outputs[2], outputs[3])):
        assert all(np.array_equal(a[k], b[k]) for k in a)


# -- the paper path end to end at 32 x 32 -----------------------------------------------------------------
@pytest.fixture(scope="module")
def paper_training(tmp_path_factory):
    """The small paper decoders trained once into an empty cache of this module's: (cache, paths, seconds), what
    that first training gave, whichever test asks first."""
    cache = tmp_path_factory.mktemp("paper-decoders")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("RHI_CACHE", str(cache))
        paths, seconds = ensure_checkpoints(small_paper_config(), progress=False)
    return cache, paths, seconds


@pytest.fixture
def paper_cache(paper_training):
    return paper_training[0]


def small_paper_config():
    return configuration.load(preset_name="paper", overrides=SMALL)


def test_paper_decoders_train_once_and_are_cached_by_their_settings(paper_training, monkeypatch):
    paper_cache, paths, seconds = paper_training
    monkeypatch.setenv("RHI_CACHE", str(paper_cache))
    config = small_paper_config()
    assert set(seconds) == {"data", "conv", "vae"}  # the training set once, then each decoder
    for kind, path in paths.items():
        assert Path(path).name.startswith(f"{kind}-r32-paper-") and Path(path).parent == paper_cache
        model, metadata = checkpoint.load(path, resolution=32)
        assert metadata["preset"] == "paper" and metadata["settings"]["channels_last"] is True
        assert metadata["sizes"]["channels"] == [128, 64, 32, 16] and metadata["sizes"]["hidden"] == 1024
        # the stop check ran after every epoch and is kept with the checkpoint
        assert len(metadata["hand_error_checks_cm"]) == metadata["epochs_run"]
        assert all(w.is_contiguous() for w in model.state_dict().values())
    stamps = {kind: Path(path).stat().st_mtime_ns for kind, path in paths.items()}
    again, seconds = ensure_checkpoints(config, progress=False)
    assert again == paths and seconds == {}  # cached: nothing trained the second time
    assert {kind: Path(path).stat().st_mtime_ns for kind, path in again.items()} == stamps
    default = configuration.load(overrides={key: value for key, value in SMALL.items()})
    assert checkpoint_path("conv", default) != paths["conv"]  # the default preset's decoder is another one


def test_rhi_experiment_with_the_paper_preset_runs_end_to_end_at_32_px(paper_cache, monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("RHI_CACHE", str(paper_cache))
    config = write(tmp_path / "small.toml", "[train]\nsamples = 96\nepochs = 2\npatience = 2\nquality_poses = 4\n"
                                            "threads = 1\n")
    out = tmp_path / "run"
    status = main(["experiment", "--preset", "paper", "--config", config, "--resolution", "32", "--trials", "1",
                   "--steps", "20", "--device", "cpu", "--out", str(out)])
    assert status == 0, capsys.readouterr().err
    run = json.loads((out / "run.json").read_text())
    assert run["device"] == "cpu" and run["timings_s"]["training"] == {}  # the decoders above, from the cache
    assert run["configuration"]["train"]["preset"] == "paper" and run["configuration"]["decoder"]["fast"] is True
    assert run["checkpoints"] == ensure_checkpoints(small_paper_config(), progress=False)[0]
    rows = (out / "summary.csv").read_text().strip().splitlines()
    assert len(rows) == 1 + 2 * 3 * 2


# -- the bench ------------------------------------------------------------------------------------------
def test_the_bench_runs_the_protocol_with_trained_decoders_when_they_are_cached(quick_cache, monkeypatch, tmp_path):
    settings = dataclasses.replace(QUICK, protocol_trained="quick", threads=1)
    monkeypatch.setenv("RHI_CACHE", str(tmp_path))  # nothing cached: the untrained decoder
    assert bench_protocol.trained_protocol(settings) is None
    monkeypatch.setenv("RHI_CACHE", str(quick_cache))
    config, paths = bench_protocol.trained_protocol(settings)
    assert set(paths) == {"conv", "vae"} and all(Path(p).parent == quick_cache for p in paths.values())
    row = bench_protocol.protocol_run(settings)
    trials = len(config["experiment"]["decoders"]) * 3 * 2 * config["experiment"]["trials"]
    assert row["trained"] is True and row["checkpoints"] == paths and "trained: conv" in row["weights"]
    assert (row["trials"], row["steps"]) == (trials, settings.protocol_steps)
    assert math.isclose(row["agent_steps_per_s"], trials * settings.protocol_steps / row["seconds"])
    assert row["stepping_agent_steps_per_s"] >= row["agent_steps_per_s"]
    untrained = bench_protocol.protocol_run(dataclasses.replace(settings, protocol_trained=""))
    assert untrained["trained"] is False and untrained["weights"].startswith("untrained")


def test_the_training_bench_times_both_paths_of_both_decoders():
    report = training_bench.training_rates(configuration.load(quick=True), steps=1, threads=1)
    for kind in ("conv", "vae"):
        rows = report["decoders"][kind]
        for path, row in (("before", rows["before"]), ("after", rows["after"])):
            assert math.isclose(row["samples_per_s"], row["batch_size"] * row["steps"] / row["step_s"])
            assert sum(row["phase_s"].values()) <= row["step_s"] * 1.001 and row["phase_s"]["backward"] > 0
        assert (rows["before"]["encoder_order"], rows["after"]["encoder_order"]) == ("conv-relu-pool",
                                                                                      "conv-pool-relu")
        assert math.isclose(rows["speedup"], rows["after"]["samples_per_s"] / rows["before"]["samples_per_s"])
    assert report["decoders"]["conv"]["before"]["phase_s"]["encoder"] == 0
    assert report["decoders"]["vae"]["after"]["phase_s"]["encoder"] > 0
    assert "conv" in training_bench.table(report)


# -- the visual variance at the paper's scale ------------------------------------------------------------
def test_the_shipped_paper_calibration_sweep_runs_the_paper_preset(tmp_path):
    from rhi.master.sweeps import plan
    sweep = plan.load(ROOT / "docs" / "sweeps" / "paper_visual_variance.toml")
    paper = configuration.load(preset_name="paper")
    assert [point["decoder.visual_variance"] for point in sweep.points] == [1.0, 10.0, 20.0, 30.0, 60.0]
    for config in sweep.configs:  # the paper preset's configuration, but for the swept key and one trial
        assert config["decoder"]["visual_variance"] in (1.0, 10.0, 20.0, 30.0, 60.0)
        assert {**config, "decoder": {**config["decoder"], "visual_variance": 20.0},
                "experiment": {**config["experiment"], "trials": 5}} == paper
    assert len(sweep.trials) == 5 * 2 * 3 * 2
    for text, message in (("quick = true\npreset = 'paper'", "either sweep.quick or sweep.preset"),
                          ("preset = 'huge'", "sweep.preset = 'huge' is not one of paper")):
        with pytest.raises(ConfigError, match=message):
            plan.load(write(tmp_path / "s.toml", f"[sweep]\n{text}\n"))


def test_the_trial_gif_is_enlarged_only_up_to_64_px():
    from rhi.master.outputs.animation import frames
    from rhi.master.config.protocol import rubber_pose
    mu = np.tile(kinematics.REST_POSE, (21, 1))
    balls = np.tile([-0.45, 0.6], (21, 1))
    assert [frames(mu, rubber_pose(-0.15), balls, side)[0].size for side in (32, 64, 128)] == [(96, 96), (192, 192),
                                                                                               (128, 128)]
    assert len(frames(mu, rubber_pose(-0.15), balls, 32)) == 3  # every 10th step of 21


def test_the_documented_table_of_the_preset_is_the_shipped_file_and_the_defaults():
    """docs/configuration.md's generated table (key | paper | default | why) against master/config/presets/paper_256.toml."""
    from docs_tables import rows

    from rhi.master.decoders.training import STOP_POSES
    shown = {row[0].strip("`"): [cell.strip("`") for cell in row[1:3]] for row in rows("configuration.md", "paper-preset")}
    with open(ROOT / "master" / "config" / "presets" / "paper_256.toml", "rb") as file:
        shipped = dict(flatten(tomllib.load(file)))
    default = dict(flatten(configuration.load()))
    assert set(shown) == set(shipped)
    for key, (paper, was) in shown.items():
        assert tomllib.loads(f"a = {paper}\nb = {was}") == {"a": shipped[key], "b": default[key]}, key
    assert f"read off {STOP_POSES} held-out poses" in (ROOT / "docs" / "decoders.md").read_text()


def test_rhi_train_with_the_paper_preset_at_32_px_prints_the_checks(tmp_path, capsys):
    config = write(tmp_path / "t.toml", "[experiment]\nresolution = 32\n[train]\nsamples = 64\nepochs = 2\npatience = 2\n"
                                        "quality_poses = 0\nthreads = 1\nstop_hand_error_cm = 50.0\n")
    out = tmp_path / "conv.pt"
    assert main(["train", "--preset", "paper", "--decoder", "conv", "--config", config, "--device", "auto",
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    metadata = checkpoint.load(out)[1]
    assert metadata["preset"] == "paper" and metadata["resolution"] == 32 and "device" not in metadata
    # a check of at most 50 cm is met after the first epoch: training stopped there
    assert metadata["epochs_run"] == 1 and len(metadata["hand_error_checks_cm"]) == 1
    assert "(stopped: at most 50.0 cm)" in printed and "conv decoder (paper, 32 px)" in printed
