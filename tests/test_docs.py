"""docs/ against the code: every generated table is what `python -m rhi.master.reference` writes now, and the
tables' keys, defaults, ports and columns are read back and compared with what the code uses and writes."""
from __future__ import annotations

import csv
import math
import tomllib
from pathlib import Path

import pytest

from docs_tables import DOCS, block, names, rows
from rhi.master import config as configuration
from rhi.master.reference.__main__ import blocks, regenerate
from rhi.master.reference.tables import TABLES

ROOT = DOCS.parent


def header(path: Path) -> list[str]:
    with open(path, newline="") as file:
        return next(csv.reader(file))


def test_every_generated_table_in_docs_is_what_the_code_writes_now():
    pages = sorted(DOCS.glob("*.md"))
    found = {name: page for page in pages for name in blocks(page.read_text())}
    assert set(found) == set(TABLES), "each generated table appears in exactly one docs page"
    tables = {name: make() for name, make in TABLES.items()}
    for page in pages:
        text = page.read_text()
        for name, shown in blocks(text).items():
            assert shown == tables[name], f"docs/{page.name}, table {name}: stale (run python -m rhi.master.reference)"
        assert regenerate(text, tables) == text


def test_the_configuration_table_lists_every_key_with_its_default():
    shown = {row[0].strip("`"): row[1].strip("`") for row in rows("configuration.md", "configuration-keys")}
    defaults = configuration.defaults()

    def leaves(table, prefix=""):
        for key, value in table.items():
            if isinstance(value, dict) and prefix != "quick.":
                yield from leaves(value, f"{prefix}{key}.")
            else:
                yield f"{prefix}{key}", value

    expected = dict(leaves(defaults))
    run = configuration.load()
    assert list(shown) == list(expected)
    for key, text in shown.items():
        assert tomllib.loads(f"a = {text}")["a"] == expected[key], key
    for key, value in expected.items():  # what a run uses: the loaded configuration, [quick] aside
        if not key.startswith("quick."):
            table, _, name = key.rpartition(".")
            loaded = run
            for part in table.split("."):
                loaded = loaded[part]
            assert loaded[name] == value or (math.isnan(value) and math.isnan(loaded[name])), key


def test_the_preset_table_is_the_shipped_preset_over_the_defaults():
    preset = configuration.preset("paper")
    default = configuration.load()
    found = {}
    for key, paper, was, _ in rows("configuration.md", "paper-preset"):
        table, name = key.strip("`").split(".")
        found[key.strip("`")] = tomllib.loads(f"a = {paper.strip('`')}\nb = {was.strip('`')}")
        assert found[key.strip("`")] == {"a": preset[table][name], "b": default[table][name]}, key
    assert set(found) == {f"{table}.{name}" for table, keys in preset.items() for name in keys}


def test_the_output_column_tables_are_the_shipped_files_headers():
    assert names("configuration.md", "summary-columns") == header(DOCS / "summary.csv")
    assert names("configuration.md", "summary-columns") == header(DOCS / "paper" / "summary.csv")
    documented = names("sweeps.md", "phenomenon-columns")
    for table in sorted((DOCS / "phenomena").glob("*.csv")):
        assert [documented[0], *documented[2:]] == [header(table)[0], *header(table)[2:]], table.name
    sweep = header(DOCS / "sweeps" / "paper_visual_variance" / "summary.csv")
    documented = block("sweeps.md", "sweep-columns").split("`summary.csv`:")[1]
    assert [line.split("|")[1].strip(" `") for line in documented.splitlines()[3:] if line.startswith("| ")] == [
        "KEY" if column == "decoder.visual_variance" else column for column in sweep]


def test_the_body_table_marks_exactly_the_body_contract():
    from rhi.components.body.contract import BODY_CONTRACT
    contract = {v.name: v for v in BODY_CONTRACT}
    shown = {row[0].strip("`"): row for row in rows("fmi.md", "body-ports")}
    assert {name for name, row in shown.items() if row[6] == "yes"} == set(contract)
    for name, variable in contract.items():
        assert shown[name][1:4] == [variable.causality, variable.type, variable.unit or "1"], name


def test_an_unknown_output_column_is_refused_until_it_is_documented(monkeypatch):
    from rhi.master.outputs import tables
    from rhi.master.reference import tables as reference
    monkeypatch.setattr(tables, "SUMMARY_COLUMNS", [*tables.SUMMARY_COLUMNS, "new_thing_kg"])
    with pytest.raises(KeyError, match="new_thing_kg"):
        reference.summary_columns()


# docs/fit/'s group recoveries, in the order docs/fit.md reports them
GROUP_RECOVERIES = ("group_recovery", "group_recovery_n20", "group_recovery_n20_probes", "group_recovery_n20_combined",
                    "group_recovery_n20_combined_1000", "group_recovery_n20_combined_ensemble", "group_recovery_n20_30s")


def test_the_fit_pages_tables_are_made_from_the_shipped_fits():
    from rhi.master.fit.report import results_markdown

    page = (DOCS / "fit.md").read_text()
    variants = ("recovery_zscore", "recovery_bounded", "recovery_ensemble")
    for folder in ("recovery", *variants, "human/kocur2022", *GROUP_RECOVERIES):
        tables = results_markdown(DOCS / "fit" / folder)
        first = tables.split("\n\n")[0]  # the variants' page shows their calibration table only
        assert (first if folder in variants else tables) in page, folder


def test_the_paper_length_recovery_is_what_its_shipped_files_plan():
    """docs/fit/group_recovery_n20_30s/run.json was made from the shipped .toml and .csv: the same statistics, the
    same settings and the same configuration (1500 steps, the probe at 6 s), as read_plan reads them today."""
    import json

    from rhi.master.fit.data import read_data
    from rhi.master.fit.plan import read_plan
    from rhi.master.fit.run import data_statistic_names

    run = json.loads((DOCS / "fit" / "group_recovery_n20_30s" / "run.json").read_text())
    data = read_data(DOCS / "fit" / "group_recovery_n20_30s.csv")
    plan = read_plan(DOCS / "fit" / "group_recovery_n20_30s.toml", data)
    assert data_statistic_names(data, plan) == run["statistics"] and len(run["statistics"]) == 16
    assert {key: plan.settings[key] for key in run["settings"]} == run["settings"]
    assert plan.base["experiment"] == run["configuration"]["experiment"]
    assert (plan.base["experiment"]["steps"], plan.base["experiment"]["probe_times"]) == (1500, [6.0])


def test_the_fit_pages_pilot_and_screen_numbers_are_their_tables():
    """docs/fit.md's trial-length pilot rows and screen numbers ("Which statistic carries Σv's spread") as
    docs/fit/pilots/trial_length.csv and screen.csv give them."""
    page = (DOCS / "fit.md").read_text()
    pilots = DOCS / "fit" / "pilots"
    with open(pilots / "trial_length.csv", newline="") as file:
        rows = {(row["stimulation"], row["statistic"]): row for row in csv.DictReader(file)}
    labels = {("sync", "drift_at_6s_cm"): "drift at 6 s", ("sync", "drift_at_12s_cm"): "drift at 12 s",
              ("sync", "drift_cm"): "drift at 30 s (final)", ("sync", "force_n"): "force at 30 s",
              ("async", "drift_cm"): "async drift at 30 s"}
    for key, label in labels.items():
        row = rows[key]
        signed = [f"{float(row[name]):+.2f}".replace("-", "\u2212")
                  for name in ("visual_variance", "proprioceptive_variance", "gamma0")]
        assert f"| {label} | {' | '.join(signed)} | {row['r2']} |" in page, label
    with open(pilots / "screen.csv", newline="") as file:
        screened = {row["data"]: row["population.decoder.visual_variance.log_sd_r"] for row in csv.DictReader(file)}
    words = {"group_recovery_n20_combined.csv": "the 20 statistics above {}",
             "screen_contrast.csv": "30 statistics) {}", "screen_percentiles.csv": "90th percentiles {}",
             "screen_pretouch_correlations.csv": "with the force) {}"}
    flat = " ".join(page.split())
    for name, phrase in words.items():
        assert phrase.format(screened[name]) in flat, name


def test_the_shipped_fits_coverage_is_that_of_their_ranks():
    """calibration.csv's coverage against recovery.csv's ranks, by hand: with L = 99 samples a truth is inside
    the central 50 % interval when its rank is 25 to 74, inside the 90 % interval when it is 5 to 94."""
    import csv

    for folder in ("recovery", "recovery_noise", "human/kocur2022", *GROUP_RECOVERIES):
        with open(DOCS / "fit" / folder / "recovery.csv", newline="") as file:
            rows = list(csv.DictReader(file))
        with open(DOCS / "fit" / folder / "calibration.csv", newline="") as file:
            for row in csv.DictReader(file):
                ranks = [int(r[row["parameter"] + "_rank"]) for r in rows]
                assert float(row["coverage_50"]) == sum(25 <= r <= 74 for r in ranks) / len(ranks), folder
                assert float(row["coverage_90"]) == sum(5 <= r <= 94 for r in ranks) / len(ranks), folder


def test_the_noisy_recovery_s_noise_is_derived_as_its_comments_say():
    """1.13 cm (van Beers et al. 1998's upper end, one lateral localisation): the drift's sd is that of a
    difference of two, the force's one localisation through default_run.csv's synchronous force per drift."""
    import math
    from rhi.master.fit.data import read_data
    from rhi.master.fit.plan import read_plan

    data = read_data(DOCS / "fit" / "default_run.csv")
    plan = read_plan(DOCS / "fit" / "recovery_noise.toml", data)
    value = dict(zip(data.statistic_names(), data.observed[0]))
    newton_per_cm = sum(value[f"force_n[{side}/sync]"] / value[f"drift_cm[{side}/sync]"]
                        for side in ("left", "right")) / 2
    assert round(newton_per_cm, 4) == 0.0587
    # each figure is rounded to its last digit: half a unit of it, and of 1.13, carried through
    assert abs(plan.noise["drift_cm"] / math.sqrt(2) - 1.13) <= 0.005 + 0.005 / math.sqrt(2)
    assert abs(plan.noise["force_n"] - 1.13 * newton_per_cm) <= 0.0005 + 0.005 * newton_per_cm


def test_the_noisy_recovery_s_held_out_arithmetic_is_as_the_page_says():
    """The page's figures on the held-out participants: the binomial ones (scipy) and the random looks' truths
    (the prior draws of seeds 0, 1 and 2, read again with draw_prior)."""
    import numpy as np
    from scipy import stats
    from rhi.master.fit.data import read_data
    from rhi.master.fit.plan import draw_prior, read_plan

    page = " ".join((DOCS / "fit.md").read_text().split())
    binomial = stats.binom
    for n, sd, outside in ((100, "0.030", "0.06"), (200, "0.021", "0.01")):
        assert f"{(0.9 * 0.1 / n) ** 0.5:.3f}" == sd
        low, high = round(0.85 * n), round(0.95 * n)  # covering low .. high of n is inside 0.85-0.95
        assert f"{binomial.cdf(low - 1, n, 0.9) + binomial.sf(high, n, 0.9):.2f}" == outside
    assert "0.030 at 100 and 0.021 at 200, and falls outside 0.85–0.95 with probability about 0.06 and 0.01" in page
    assert f"1 − 0.95⁸ = {100 * (1 - 0.95 ** 8):.0f} %" in page
    # numpy's 5 % and 95 % quantiles of 99 samples sit at order statistics 5.9 and 94.1 (1-based, linear)
    assert f"(94.1 − 5.9)/100 = {100 * (1 + 0.95 * 98 - (1 + 0.05 * 98)) / 100:.1f} %" in page

    plan = read_plan(DOCS / "fit" / "recovery_noise.toml", read_data(DOCS / "fit" / "default_run.csv"))
    unit = [lambda v, p=p: (v - p.to_inference(p.low)) / (p.to_inference(p.high) - p.to_inference(p.low))
            for p in plan.parameters]
    sync, gamma0 = 2, 3
    seed0 = unit[sync](draw_prior(plan.parameters, 1667, 0)[1567:, sync])  # recovery.toml's 1567 + 100
    outer = int(np.sum((seed0 < 0.05) | (seed0 > 0.95)))
    assert f"with {outer} of the 100 sync_sd truths in the prior's outer tenth, where a posterior as wide as the " \
           f"prior covers {1 - outer / 100:.2f}" in page
    seed2 = draw_prior(plan.parameters, 1767, 2)[1567:]
    assert f"its truths themselves too (KS p {stats.kstest(unit[sync](seed2[:, sync]), 'uniform').pvalue:.3f}" in page
    pooled = np.concatenate([draw_prior(plan.parameters, 200, 1), seed2])  # the selection set and seed 2's
    top_fifth = int(np.sum(unit[gamma0](pooled[:, gamma0]) >= 0.8))
    assert f"Those 400 hold {top_fifth} γ0 truths in the prior's top fifth" in page


def test_the_floor_graph_is_read_from_the_imports_a_floor_above_each_floor_it_imports():
    from rhi.master.reference.imports import floor_edges, floor_table

    sources = {  # written here with the graph they make: lazy, relative and rhi.-prefixed imports all count
        "master/__init__.py": "from rhi.master.cosim import System\n",
        "master/cosim/loop.py": "from rhi.components.component import Component\nimport numpy\n",
        "master/tasks/run.py": "def f():\n    from rhi.master.cosim import loop\n    from rhi.components.body import x\n",
        "components/component.py": "from .variables import Variable\n",
        "components/variables.py": "",
        "components/body/x.py": "from ..component import Component\nfrom .y import z\n",
        "rhi/api.py": "from rhi.master.tasks import run\nfrom rhi import api\n",
    }
    assert floor_edges(sources) == {"master": {"master/cosim"}, "master/cosim": {"components"},
                                    "master/tasks": {"master/cosim", "components/body"}, "components": set(),
                                    "components/body": {"components"}, "rhi": {"master/tasks"}}
    # heights by hand: components 0; components/body, master/cosim 1; master, master/tasks 2; rhi 3 (ties by name)
    assert floor_table(floor_edges(sources)).splitlines()[2:] == [
        "| `rhi` | `master/tasks` |", "| `master` | `master/cosim` |",
        "| `master/tasks` | `components/body`, `master/cosim` |", "| `components/body` | `components` |",
        "| `master/cosim` | `components` |", "| `components` | nothing of the project |"]


def test_floors_in_a_circle_have_no_order_and_are_named():
    from rhi.master.reference.imports import top_down

    with pytest.raises(ValueError, match="circle: master/a, master/b"):
        top_down({"master/a": {"master/b"}, "master/b": {"master/a"}, "components": set()})
