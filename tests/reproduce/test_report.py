"""The HTML report: every section, self-contained, and its numbers equal the run store's."""

from __future__ import annotations

import html
import json
import re

import numpy as np
import pytest
from scipy.stats import beta
from typer.testing import CliRunner

from worldagent.cli import app
from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.reports.html import SECTIONS, build_report
from worldagent.reproduce.manifest import Manifest
from worldagent.reproduce.presets import get_preset
from worldagent.store import RunStore, world_digest


def data_values(page: str) -> dict[str, float]:
    """{data-key: value} of every machine-readable number; a key printed twice must agree."""
    found: dict[str, float] = {}
    for key, value in re.findall(r'data-key="([^"]+)" data-value="([^"]+)"', page):
        number = float(value)
        if key in found:
            assert np.isclose(found[key], number, equal_nan=True), key
        found[key] = number
    return found


def episode_mean(evaluation, metric: str) -> float:
    return float(np.mean([float(e[metric]) for e in evaluation.episodes]))


def normalised_mean(evaluation) -> float:
    """A racing world's mean normalised return: ``spec.metrics.normalise`` of each episode's return (paper §6)."""
    spec = registry.get("racing")
    return float(np.mean(spec.metrics.normalise([e["return"] for e in evaluation.episodes], spec.make_env()[1])))


def expected_racing(out) -> dict[str, float]:
    """The racing headline numbers, recomputed here straight from the store and influence.json."""
    with RunStore(out / "racing" / "store.sqlite", create=False) as store:
        random = store.evaluations("random-return-s0")
        low = min(store.evaluations("cmaes-min-return-s0"), key=lambda e: e.score)
        high = max(store.evaluations("cmaes-max-return-s0"), key=lambda e: e.score)
    values = {
        "racing.random.mean_raw": np.mean([e.score for e in random]),
        "racing.random.mean_normalised": np.mean([normalised_mean(e) for e in random]),
        "racing.random.crashed": np.mean([episode_mean(e, "crashed") for e in random]),
    }
    for label, found in (("min", low), ("max", high)):
        values.update(
            {
                f"racing.{label}.raw": found.score,
                f"racing.{label}.normalised": normalised_mean(found),
                f"racing.{label}.crashed": episode_mean(found, "crashed"),
            }
        )
    summary = json.loads((out / "racing" / "influence" / "influence.json").read_text())["summary"]
    for which in ("default", "influenced"):
        values[f"racing.influence.crashed_{which}"] = summary["crashed"][which]["mean"]
    spec = registry.get("racing")
    before, after = (float(spec.metrics.normalise(summary["return"][which]["mean"], spec.make_env()[1])) for which in ("default", "influenced"))
    values["racing.influence.reward_change_pct"] = 100 * (after - before) / abs(before)
    return values


def test_the_report_is_one_self_contained_file_with_every_section(racing_run):
    out, _ = racing_run
    page = (out / "report.html").read_text()
    for anchor, title in SECTIONS:
        assert f'<section id="{anchor}">' in page and f"<h2>{title}</h2>" in page.replace("&#x27;", "'")
    images = re.findall(r'<img [^>]*src="([^"]+)"', page)
    assert len(images) >= 6 and all(src.startswith("data:image/png;base64,") for src in images)
    assert not re.search(r'(src|href)="(?!data:|#)', page)  # nothing to fetch: it opens offline
    assert "<table>" in page and "worlds to reach random q0.1" in page
    for number in ("0.87", "0.13", "0.99", "0", "0.11", "0.04", "-5"):  # racing's spec.paper
        assert f"<td class='num'>{number}</td>" in page, number  # the paper's values, beside ours


def test_the_reports_numbers_equal_the_stores(racing_run):
    out, _ = racing_run
    shown = data_values((out / "report.html").read_text())
    for key, value in expected_racing(out).items():
        assert np.isclose(shown[key], value, rtol=1e-12, atol=1e-12, equal_nan=True), key
    assert not any(key.startswith("harvest.") for key in shown)  # harvest was not run: no section of its own


def test_the_report_shows_its_sample_efficiency_table_from_the_store(racing_run):
    from worldagent.reports.comparison import sample_efficiency

    out, _ = racing_run
    shown = data_values((out / "report.html").read_text())
    with RunStore(out / "racing" / "store.sqlite", create=False) as store:
        runs = {opt: [np.array([e.score for e in store.evaluations(f"compare-{opt}-min-return-s0")][:21])] for opt in ("cmaes", "bo", "random")}
        random = np.array([e.score for e in store.evaluations("random-return-s0")])
    for row in sample_efficiency(runs, random):
        assert np.isclose(shown[f"racing.compare.{row['optimiser']}.best_mean"], row["best_mean"])
        assert np.isclose(shown[f"racing.compare.{row['optimiser']}.mean_sampled"], row["mean_sampled"])


def test_report_command_rebuilds_the_report(racing_copy):
    (racing_copy / "report.html").unlink()
    result = CliRunner().invoke(app, ["report", str(racing_copy)])
    assert result.exit_code == 0, result.output
    assert (racing_copy / "report.html").is_file()


def test_missing_phases_show_as_not_run(tmp_path):
    manifest = Manifest.open(tmp_path)
    manifest.data.update(preset="tiny", envs=["racing", "harvest"], config={}, versions={}, device="cpu")
    manifest.start("racing/dataset", {"seed": 0})
    manifest.finish("racing/dataset", {"summary": "256 worlds"})
    page = build_report(tmp_path).read_text()
    for anchor, _ in SECTIONS:
        assert f'<section id="{anchor}">' in page
    assert page.count("not run") >= 10


def test_a_directory_without_a_run_is_refused(tmp_path):
    with pytest.raises(WorldagentError, match="has no manifest.json; run `worldagent reproduce"):
        build_report(tmp_path)
    result = CliRunner().invoke(app, ["report", str(tmp_path)])
    assert result.exit_code == 2 and "no manifest.json" in result.output


def test_reproduce_command_shows_presets_and_refuses_changes_in_one_line(racing_copy):
    shown = CliRunner().invoke(app, ["reproduce", "--preset", "quick", "--show"])
    assert shown.exit_code == 0 and json.loads(shown.output)["name"] == "quick"
    changed = CliRunner().invoke(app, ["reproduce", "--preset", "tiny", "--env", "racing", "--algo", "acktr", "--out", str(racing_copy), "--quiet"])
    assert changed.exit_code == 2 and "--restart agent" in changed.output and "Traceback" not in changed.output


def fake_evaluation(campaign: str, score: float, episodes: list[dict]):
    from worldagent.store import Evaluation

    return Evaluation(campaign, 0, 0, np.zeros(10), score, episodes, 0.0, 0.0)


def test_harvest_reward_is_normalised_by_the_runs_best_episode():
    from worldagent.envs import registry
    from worldagent.reports.results import Scale, headlines, normalised_means, world_summary

    spec = registry.get("harvest")
    worlds = [
        fake_evaluation(
            "random", 60.0, [{"group_reward": 40.0, "conflict": 0.5, "equality": 0.25}, {"group_reward": 80.0, "conflict": 0.0, "equality": 0.75}]
        ),
        fake_evaluation("random", 200.0, [{"group_reward": 200.0, "conflict": 0.0, "equality": 1.0}]),
    ]
    scale = Scale(spec.make_env()[1], 200.0)
    assert np.allclose(normalised_means(spec, worlds, scale), [0.3, 1.0])
    low = world_summary(spec, worlds[0], scale)
    assert (low["raw"], low["conflict"], low["equality"]) == (60.0, 0.25, 0.5) and np.isclose(low["normalised"], 0.3)
    influence = {
        "summary": {
            "group_reward": {"default": {"mean": 100.0}, "influenced": {"mean": 90.0}},
            "conflict": {"default": {"mean": 0.5}, "influenced": {"mean": 0.1}},
            "equality": {"default": {"mean": 0.3}, "influenced": {"mean": 0.8}},
        }
    }
    results = {"harvest": {"random": {"mean_normalised": 0.65, "mean_raw": 130.0}, "min": low, "influence": influence, "scale": scale}}
    rows = {row.key: row for row in headlines(results)}
    assert rows["harvest.random.mean_normalised"].ours == 0.65 and rows["harvest.random.mean_normalised"].paper == 0.61
    assert np.isclose(rows["harvest.min.normalised"].ours, 0.3) and rows["harvest.max.normalised"].ours is None
    assert (rows["harvest.influence.conflict_default"].ours, rows["harvest.influence.equality_influenced"].ours) == (0.5, 0.8)
    assert rows["harvest.influence.conflict_default"].paper == 0.51
    assert np.isclose(rows["harvest.influence.reward_change_pct"].ours, -10.0)
    assert not any(key.startswith("racing.") for key in rows)  # racing not run: no rows


def test_the_failure_atlas_section_is_recomputed_from_the_store(racing_run):
    """Coverage, failing worlds and the Monte Carlo estimate, recomputed here from the raw rows."""
    out, _ = racing_run
    page = (out / "report.html").read_text()
    shown = data_values(page)
    spec = registry.get("racing")
    with RunStore(out / "racing" / "store.sqlite", create=False) as store:
        atlas = store.evaluations("atlas-min-return-s0", with_worlds=True)
        grid = store.campaign("atlas-min-return-s0").config["atlas"]["grid"]
        mc = store.evaluations("failure-mc-crash_rate>0.5-s0")
        assert store.campaign("failure-is-crash_rate>0.5-s0") is not None
    cells, elites = set(), {}
    for evaluation in atlas:
        world = spec.world_from_arrays(evaluation.world)
        index = []
        for name, count, (low, high) in zip(grid["descriptors"], grid["cells"], grid["ranges"]):
            index.append(min(count - 1, max(0, int(np.floor((spec.metrics.descriptors[name](world) - low) / (high - low) * count)))))
        cells.add(tuple(index))
        if tuple(index) not in elites or evaluation.score < elites[tuple(index)].score:
            elites[tuple(index)] = evaluation  # each cell's lowest return, the earliest on ties
    failing = [e for e in atlas if episode_mean(e, "crashed") > 0.5]
    # the corrected archive: every elite's stored confirmation (the preset's elite_confirm fresh episodes), a crash rate
    # beyond 0.5 by its exact interval
    repeats = get_preset("tiny").elite_confirm
    with RunStore(out / "racing" / "store.sqlite", create=False) as store:
        fresh = {c.world: [float(e["crashed"]) for e in c.episodes] for c in store.confirmations() if c.repeats == repeats}
    crashes = [fresh[world_digest(e.world)] for e in elites.values()]
    assert shown["racing.atlas.found.failing_cells"] == sum(episode_mean(e, "crashed") > 0.5 for e in elites.values())
    assert shown["racing.atlas.confirmed.failing_cells"] == sum(beta.ppf(0.025, sum(c), len(c) - sum(c) + 1) > 0.5 for c in crashes if sum(c))
    assert "racing.atlas.confirmed.qd_score" in shown
    assert shown["racing.atlas.evaluations"] == len(atlas) == 105
    assert shown["racing.atlas.coverage"] == pytest.approx(len(cells) / np.prod(grid["cells"]))
    assert shown["racing.atlas.failing"] == len(failing)
    assert shown["racing.atlas.distinct_failing"] == len({e.world["road"].tobytes() for e in failing})
    hits = sum(episode_mean(e, "crashed") > 0.5 for e in mc)
    assert shown["racing.failure.mc.estimate"] == pytest.approx(hits / len(mc)) and shown["racing.failure.mc.worlds"] == len(mc) == 64
    assert shown["racing.failure.mc.low"] <= shown["racing.failure.mc.estimate"] <= shown["racing.failure.mc.high"]
    assert shown["racing.failure.is.episodes"] == 2 * shown["racing.failure.is.worlds"] > 0
    assert "Failure groups" in page and "How likely is" in page


def test_agents_that_failed_to_learn_are_flagged_in_the_report(racing_run):
    out, _ = racing_run  # the tiny preset's agents train 64 episodes: they never lap
    page = (out / "report.html").read_text()
    flags = re.findall(r"data-flag='failed-training'>Warning: the (\S+) agent", page)
    assert flags == ["default-s0", "influenced-s0"]
    assert "WARNING: the influenced-s0 agent laps in only" in Manifest.read(out).data["phases"]["racing/influence"]["outputs"]["summary"]


def test_the_report_says_how_both_influence_arms_trained(racing_run):
    out, _ = racing_run
    result = json.loads((out / "racing" / "influence" / "influence.json").read_text())
    shown = html.unescape(re.search(r"data-field='influence-regime'>Both arms' training: (.*?)\.</p>", (out / "report.html").read_text()).group(1))
    assert shown.startswith(f"{result['algo']}, {result['config']['episodes']} episodes each; beside {result['algo']}'s defaults: ")
    changed = result["config"]["training"]["num_envs"]  # the tiny preset's train_envs, not the algorithm's 16
    assert f"num_envs {changed}" in shown and changed != 16
    assert "gamma" not in shown  # a setting left at the algorithm's default is not listed
