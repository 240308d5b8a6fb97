"""`rhi bench` with tiny settings: every key, positive numbers, and numbers consistent with each other.

The bench reports speed; these tests check that what it reports is computed right (FLOPs against
a hand count, rates against counts and seconds), and that the baseline agent computes what the
exact integrator computes.
"""
import dataclasses
import json
import math

import numpy as np
import pytest

from master.bench import suite as bench
from master.bench.report import table
from master.commands.bench import run_bench
from master.commands.cli import build_parser
from master.cosim import ConfigError
from master.bench.baseline import PaperStyleAgent
from tests.test_batching import STEPS, reference_runs, tiny_config, tiny_model

MODES = ("baseline", "exact_single", "exact_batched", "exact_batched_optimised", "fast")


@pytest.fixture(scope="module")
def report():
    return bench.run_suite(dataclasses.replace(bench.QUICK, threads=1))


def test_tiny_decoder_flops_match_a_hand_count(report):
    # tiny preset at 32x32: Linear 2->64, Linear 64->16*4*4, ConvT 16->16 (4x4 in), Conv 16->16 (8x8),
    # ConvT 16->8 (8x8 in), Conv 8->8 (16x16), ConvT 8->1 (16x16 in); kernels 4x4 (ConvT), 3x3 (Conv).
    macs = 2 * 64 + 64 * 256 + 16 * 16 * 16 * 16 + 16 * 16 * 9 * 64 + 16 * 8 * 16 * 64 + 8 * 8 * 9 * 256 + 8 * 16 * 256
    flops = report["presets"]["tiny-32"]["flops"]
    assert flops["forward_per_trial"] == 2 * macs == 1_081_600
    # FlopCounterMode ignores biases and activations as the analytic count does.
    assert flops["forward_per_trial_counted"] == flops["forward_per_trial"]
    # Two JVPs: at least a primal and a tangent pass each; the baseline: forward plus input and weight grads.
    assert flops["exact_step_per_trial"] >= 4 * flops["forward_per_trial"]
    assert flops["optimised_step_per_trial"] == 3 * flops["forward_per_trial"]  # a primal and two tangent passes
    # ... of which the last layer (ConvT 8 -> 1, 16 x 16 in) runs as a sub-pixel convolution with 2.25x its FLOPs
    assert flops["optimised_step_counted"] == flops["optimised_step_per_trial"] + 3 * 1.25 * (2 * 8 * 16 * 256)
    assert 2 * flops["forward_per_trial"] < flops["baseline_step_per_trial"] <= 3 * flops["forward_per_trial"]


def test_rates_are_positive_and_consistent(report):
    peak = report["matmul_peak"]
    assert math.isclose(peak["flop_per_s"], 2 * peak["size"] ** 3 / peak["seconds"])
    block = report["presets"]["tiny-32"]
    for mode in MODES:
        row = block["modes"][mode]
        assert row["trials"] == (1 if mode in ("baseline", "exact_single") else 6)
        assert row["steps"] >= 2 and row["seconds"] > 0 and row["decoder_s"] > 0
        assert math.isclose(row["agent_steps_per_s"] * row["seconds"], row["trials"] * row["steps"])
        assert 0 < row["share"]["decoder"] < 1 and sum(row["share"].values()) < 1 + 1e-9
        if mode != "fast":
            key = {"baseline": "baseline_step_per_trial",
                   "exact_batched_optimised": "optimised_step_per_trial"}.get(mode, "exact_step_per_trial")
            per_step = block["flops"][key]
            assert row["decoder_flops"] == per_step * row["trials"] * row["steps"]
            assert math.isclose(row["decoder_flop_per_s"], row["decoder_flops"] / row["decoder_s"])
            assert math.isclose(row["peak_fraction"], row["decoder_flop_per_s"] / peak["flop_per_s"])
    protocol = report["protocol_fast"]
    assert (protocol["trials"], protocol["steps"]) == (6, 10)
    assert math.isclose(protocol["agent_steps_per_s"], 60 / protocol["seconds"])
    assert protocol["relinearisations_per_trial"] >= 1 and protocol["peak_rss_mb"] > 50


def test_error_overhead_memory_and_targets(report):
    error = report["fast_error"]
    assert error["trials"] == 6 and len(error["drift_exact_cm"]) == len(error["drift_fast_cm"]) == 6
    assert math.isclose(error["max_error_cm"],
                        np.abs(np.subtract(error["drift_fast_cm"], error["drift_exact_cm"])).max())
    assert error["bound_met"] == (error["max_error_cm"] <= 0.01 * error["largest_drift_cm"])
    assert math.isclose(error["decoder_points_per_trial"], sum(error["call_sizes"]) / error["trials"])
    protocol = report["protocol_fast"]  # the trained (here: error-run) decoder's calls replayed cost extra time
    assert 0 < protocol["projected_agent_steps_per_s"] < protocol["agent_steps_per_s"]
    assert report["targets"]["fast_protocol_agent_steps_per_s"]["value"] == protocol["projected_agent_steps_per_s"]
    overhead = report["master_overhead"]
    for key in ("fmpy_step_s", "master_step_s", "of_which_master_loop_s", "of_which_adapter_and_fmu_s"):
        assert overhead[key] > 0, key
    assert math.isclose(overhead["wall_ratio"], overhead["master_step_s"] / overhead["fmpy_step_s"])
    assert overhead["of_which_master_loop_s"] + overhead["of_which_adapter_and_fmu_s"] < 2 * overhead["master_step_s"]
    assert report["memory"]["bench_peak_rss_mb"] > 50 and report["memory"]["protocol_peak_rss_mb"] > 50
    machine = report["machine"]
    assert machine["torch_threads"] == 1 and machine["cores"] >= 1 and set(machine["cpu_flags"]) >= {"avx512_bf16"}
    assert set(report["targets"]) == {"exact_batched_peak_fraction_paper", "fast_protocol_agent_steps_per_s",
                                      "fast_drift_relative_error", "master_step_vs_fmpy_simulate_fmu",
                                      "protocol_peak_rss_mb"}
    assert report["targets"]["exact_batched_peak_fraction_paper"]["met"] is None  # no paper preset in quick
    json.dumps(report)  # --json must be able to print it


def test_table_names_every_mode_and_target(report):
    text = table(report)
    for word in (*MODES, *report["targets"], "GFLOP/s", "fmpy.simulate_fmu", "peak memory"):
        assert word in text


def test_command_arguments_and_their_errors(tmp_path):
    parser = build_parser()
    args = parser.parse_args(["bench", "--json", "--quick", "--threads", "1", "--checkpoint", "conv.pt"])
    assert (args.json, args.quick, args.threads, args.checkpoint) == (True, True, 1, "conv.pt")
    with pytest.raises(ConfigError, match="--threads -2"):
        run_bench(parser.parse_args(["bench", "--threads", "-2"]))
    with pytest.raises(ConfigError, match="--checkpoint .*missing.pt does not exist"):
        run_bench(parser.parse_args(["bench", "--checkpoint", str(tmp_path / "missing.pt")]))


def test_baseline_agent_computes_the_exact_integrators_numbers():
    """Reverse-mode (backward with grad_outputs) against forward-mode JVPs: the same trajectories."""
    trials, _, singles = reference_runs()
    exact = singles[0]
    record = PaperStyleAgent(tiny_model(), trials[0], tiny_config()).run(STEPS)
    values = exact.values
    assert np.abs(values["brain.mu"][-1, 0] - values["brain.mu"][0, 0]).max() > 0.1  # it moved
    np.testing.assert_allclose(record["mu"], values["brain.mu"][:, 0], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(record["gamma"], values["brain.gamma"][:, 0])
    np.testing.assert_allclose(record["action"][:, 0], values["brain.u_shoulder"][:, 0], rtol=0, atol=1e-6)
    np.testing.assert_allclose(record["force_x"], values["body.force_x"][:, 0], rtol=0, atol=1e-6)
