"""The fast mode's check per decoder and protocol family (rhi.master.tasks.illusion.fast_check.family), and none for a
model that runs no decoder."""
import pytest

from rhi.master import config as configuration
from rhi.master.config.protocol import make_trial
from rhi.master.decoders.cache import SHIPPED, checkpoint_path
from rhi.master.tasks.illusion import fast_check


def recording_check(calls):
    """A stand-in for the check that records the configuration each check is run on (what is checked is the
    subject here, not the drift: test_fast_check.py checks the drifts) and returns a verdict check() could write."""
    def check(config, kind, checkpoint, progress=None):
        calls.append(config)
        trials = fast_check.checked_trials(config, kind)
        return {"fast": True, "reason": "checked", "relative_error": 0.0, "bound": fast_check.DRIFT_BOUND,
                "trials": [f"{t.condition} {t.stimulation} 0" for t in trials],
                "drift_exact_cm": [1.0] * len(trials), "drift_fast_cm": [1.0] * len(trials)}
    return check


@pytest.fixture
def decoder_file(tmp_path, monkeypatch):
    """A checkpoint stand-in (the verdict's key hashes its bytes) and a cache of the test's own."""
    monkeypatch.setenv("RHI_CACHE", str(tmp_path / "cache"))
    (tmp_path / "cache").mkdir()
    path = tmp_path / "decoder.pt"
    path.write_bytes(b"weights")
    return {"conv": str(path)}


def test_a_model_that_reads_no_pixels_is_checked_for_nothing(decoder_file, monkeypatch, tmp_path):
    monkeypatch.setattr(fast_check, "check", lambda *job: pytest.fail("checked a model that runs no decoder"))
    config = configuration.load(quick=True, model_name="ownership", overrides={"decoder.fast": True})
    verdict = fast_check.verdicts(config, decoder_file)
    assert verdict == {"conv": {"fast": False, "reason": "no decoder runs: the ownership model reads no pixel term"}}
    assert not list((tmp_path / "cache").iterdir())  # nothing stored either


def test_a_causal_model_with_a_pixel_term_is_checked(decoder_file, monkeypatch):
    calls = []
    monkeypatch.setattr(fast_check, "check", recording_check(calls))
    config = configuration.load(quick=True, model_name="causal",
                                overrides={"decoder.fast": True, "causal.pixel_weight": 1.0})
    assert fast_check.verdicts(config, decoder_file)["conv"]["fast"] is True and len(calls) == 1


def test_protocols_of_one_family_share_one_check_on_the_family_s_representative(decoder_file, monkeypatch):
    calls = []
    monkeypatch.setattr(fast_check, "check", recording_check(calls))
    paper = configuration.load(quick=True, overrides={"decoder.fast": True})
    # Another schedule of the same arm, decoder and length: vision-only blocks, a probe, a stop, a hidden arm.
    scheduled = configuration.merge(paper, {
        "experiment": {"stimulations": ["vision"], "probe_times": [2.0]},
        "stimulations": {"vision": {"delay_min": 0.5, "delay_max": 0.5, "touch": False, "blocks": [[1.0, 4.0]]}},
        "stimulus": {"stop_time": 3.0, "stroke_duration": 1.0}, "rubber_arm": {"hidden_conditions": ["left"]}})
    first = fast_check.verdicts(scheduled, decoder_file)
    assert len(calls) == 1
    # The check ran the representative's trials: the shipped schedule's first stimulation (sync), every condition
    # of the protocol, the arm in view -- not the vision-only protocol's own.
    checked = fast_check.checked_trials(calls[0], "conv")
    assert [(t.condition, t.stimulation, t.arm_visible, t.touch, t.blocks) for t in checked] == \
        [(c, "sync", True, True, ()) for c in paper["experiment"]["conditions"]]
    assert checked == [make_trial(paper, "conv", c, "sync", 0) for c in paper["experiment"]["conditions"]]
    assert fast_check.verdicts(paper, decoder_file) == first and len(calls) == 1  # the family's stored verdict
    # What the decoder is asked to decode is the family's: other offsets, another length, each a new check.
    fast_check.verdicts(configuration.merge(paper, {"conditions": {"left": -0.17}}), decoder_file)
    fast_check.verdicts(configuration.merge(paper, {"experiment": {"steps": 301}}), decoder_file)
    assert len(calls) == 3


def test_the_paper_protocol_is_its_own_representative_so_the_shipped_verdicts_stand():
    config = configuration.load()
    assert fast_check.family(config) == config
    for kind in config["experiment"]["decoders"]:
        key = fast_check.verdict_key(checkpoint_path(kind, config, must_exist=True), fast_check.family(config))
        assert (SHIPPED / f"fast-check-{kind}-{key}.json").is_file()
