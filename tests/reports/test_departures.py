"""The report's first box: where a run departs from the paper, each gap's possible causes (only what the run's own record
shows: settings unlike the paper preset, the generator's gate warnings) and section; one seed said as such."""

from __future__ import annotations

import dataclasses
import re

import pytest

from worldagent.reports.departures import departures, departures_section, differs, likely_cause, run_differences
from worldagent.reports.results import Headline, influence_headlines
from worldagent.reproduce.pipeline import settings_record
from worldagent.reproduce.presets import get_preset
from worldagent.runs import PHASES


@pytest.mark.parametrize(
    ("ours", "paper", "apart"),
    [
        (0.357, 0.61, True),  # harvest random, normalised (the quick run)
        (0.071, 0.51, True),  # harvest influence conflict
        (3.4, -5.0, True),  # racing influence reward change, %: the other sign
        (0.60, 0.61, False),
        (0.04, 0.0, False),  # within 0.05 of a zero
        (None, 0.61, False),
        (0.5, None, False),
    ],
)
def test_a_number_differs_when_off_by_a_quarter_or_of_the_other_sign(ours, paper, apart):
    assert differs(ours, paper) is apart


def recorded(preset: str, env: str, phase: str, **changes) -> dict:
    """A phase's manifest entry as ``reproduce`` records it at ``preset``, with ``changes`` made to its settings."""
    about = settings_record(get_preset(preset), env, phase)
    return {"status": "done", "config": {"recorded": True}, **about, "full_config": {**about["full_config"], **changes}}


def harvest_results(seeds=(0,)):
    """What ``results.env_results`` gives for a quick-like harvest run (only what the box reads)."""
    summary = {
        "equality": {"default": {"mean": 0.671}, "influenced": {"mean": 0.659}},
        "conflict": {"default": {"mean": 0.071}, "influenced": {"mean": 0.05}},
        "group_reward": {"default": {"mean": 150.0}, "influenced": {"mean": 160.0}},
    }
    phases = {phase: recorded("paper", "harvest", phase) for phase in PHASES}
    phases["agent"] = recorded("paper", "harvest", "agent", episodes=1000)
    phases["influence"] = recorded("paper", "harvest", "influence", seeds=list(seeds))
    return {"harvest": {"phases": phases, "influence": {"summary": summary, "config": {"seeds": list(seeds)}}}}


def test_each_gap_names_its_likely_cause_and_links_its_section():
    results = harvest_results()
    rows = [Headline("harvest.random.mean_normalised", "Harvest: random worlds, mean group reward (normalised)", 0.357, 0.61)]
    rows += influence_headlines("harvest", results["harvest"])
    found = {d.row.key: d for d in departures(rows, results)}
    assert set(found) == {"harvest.random.mean_normalised", "harvest.influence.conflict_default", "harvest.influence.equality_default"}
    random = found["harvest.random.mean_normalised"]
    assert random.anchor == "random" and "1,000 training episodes (paper preset: 5,000)" in random.cause and "best single episode" in random.cause
    conflict = found["harvest.influence.conflict_default"]
    assert conflict.anchor == "influence" and conflict.cause.startswith("one seed per arm")
    assert all(row.note.startswith("one seed") for row in rows[1:])  # the headline table says so too


def test_the_box_says_the_preset_the_gaps_and_what_one_seed_cannot_show():
    results = harvest_results()
    rows = [Headline("harvest.random.mean_normalised", "Harvest: random worlds", 0.357, 0.61), *influence_headlines("harvest", results["harvest"])]
    box = departures_section(rows, results, "quick")
    assert "<code>quick</code> preset" in box and "3 of the 5 numbers the paper reports differ" in box
    assert "href='#influence'" in box and "href='#random'" in box
    (note,) = re.findall(r"<li data-flag='one-seed'>(.*?)</li>", box)
    assert "equality 0.671 → 0.659" in note and "cannot show which way" in note
    assert "data-flag='one-seed'" not in departures_section(rows, harvest_results(seeds=(0, 1, 2)), "paper")


CRASHED = Headline("racing.random.crashed", "Racing: random worlds, crashed", 0.0526, 0.11)
OVERFIT = "overfit: held-out reconstruction no better than the mean world (NLL 207.1 vs 177.5 nats per world)"


def racing_as_paper(**changes):
    """A racing run whose every phase recorded the paper preset's settings, with ``{phase: {field: value}}`` changed."""
    return {"racing": {"phases": {phase: recorded("paper", "racing", phase, **changes.get(phase, {})) for phase in PHASES}}}


def test_a_run_with_the_paper_settings_may_call_a_gap_real():
    results = racing_as_paper()
    assert run_differences(results["racing"]) == []
    cause = likely_cause(CRASHED, results)
    assert "unexplained" in cause and "real difference" in cause and "paper preset:" not in cause
    assert "every setting its phases recorded matches the paper's preset" in departures_section([CRASHED], results, "paper")


def test_each_setting_unlike_the_papers_is_named_and_the_gap_is_not_called_real():
    """The quick run's case: PPO on the route observation and a 10-epoch VAE, against ACKTR on rays and 25 epochs."""
    results = racing_as_paper(generator={"epochs": 10}, agent={"algo": "ppo", "options": {"observation": "route"}})
    cause = likely_cause(CRASHED, results)
    assert "10 VAE epochs (paper preset: 25)" in cause
    assert "training algorithm ppo (paper preset: acktr)" in cause
    assert "env option observation route (paper preset: rays)" in cause
    assert "real difference" not in cause
    # a setting the number does not depend on is listed in the box, not given as this number's cause
    results = racing_as_paper(strategic={"budget": 420})
    assert "420 worlds searched" not in likely_cause(CRASHED, results)
    minimum = Headline("racing.min.normalised", "min", 0.37, 0.13)
    assert likely_cause(minimum, results) == "settings unlike the paper preset: 420 worlds searched (paper preset: 2,100)"  # that field only
    box = departures_section([CRASHED], results, "quick")
    assert "1 of its settings differs" in box and "data-setting='racing/strategic/budget'" in box
    # an env whose searches default to BO (harvest) departs from the paper's CMA-ES in its strategic phase
    results = racing_as_paper(strategic={"optimiser": "bo"})
    assert likely_cause(minimum, results) == "settings unlike the paper preset: search optimiser bo (paper preset: cmaes)"


def test_an_omitted_setting_is_its_default_and_repeats_and_repair_count():
    """The quick preset records no options for racing (route, the default) where the paper's records rays; repeats and the repair
    are compared too."""
    quick = get_preset("quick")
    assert "options" not in quick.phase_config("racing", "agent") and quick.full_phase_config("racing", "agent")["options"]["observation"] == "route"
    ours = dataclasses.replace(get_preset("paper"), repeats=2, repair="open")
    phases = {phase: {"status": "done", **settings_record(ours, "racing", phase)} for phase in PHASES}
    found = {(d.phase, d.name): (d.ours, d.paper) for d in run_differences({"phases": phases})}
    assert found[("random", "repeats")] == (2, 8) and found[("generator", "repair")] == ("open", "nearest")
    assert {name for _, name in found} == {"repeats", "repair"}
    phases["agent"] = {"status": "done", **settings_record(quick, "racing", "agent")}
    assert ("agent", "options.observation") in {(d.phase, d.name) for d in run_differences({"phases": phases})}


def test_a_phase_without_recorded_settings_leaves_the_gap_unexplained():
    """A manifest written before the paper preset's settings were recorded beside each phase's says so, and never calls a gap real."""
    results = racing_as_paper()
    results["racing"]["phases"]["generator"] = {"status": "done", "config": {"epochs": 25}}
    cause = likely_cause(CRASHED, results)
    assert cause.startswith("unexplained: the generator phase recorded no paper-preset settings") and "real difference" not in cause


def test_the_pipeline_records_what_the_report_compares(tmp_path):
    """``reproduce`` writes each phase's settings, the paper preset's and its parents into the manifest, also for a phase done
    before they were kept, so the report never reads a preset itself."""
    from worldagent.reproduce.manifest import Manifest
    from worldagent.reproduce.pipeline import run_phase

    manifest, quick = Manifest.open(tmp_path), get_preset("quick")
    config = quick.phase_config("racing", "random")
    run_phase(manifest, "racing/random", config, lambda: {}, lambda _: None)
    assert "paper_config" not in manifest.phase("racing/random")
    run_phase(manifest, "racing/random", config, lambda: {}, lambda _: None, about=settings_record(quick, "racing", "random"))
    entry = manifest.phase("racing/random")
    assert entry["depends"] == ["generator", "agent"] and entry["paper_config"]["worlds"] == 1000 and entry["full_config"] == config


def test_the_generators_gate_warnings_join_the_box_and_the_causes():
    results = racing_as_paper()
    results["racing"]["phases"]["generator"]["outputs"] = {"warnings": [OVERFIT]}
    results["racing"]["quality"] = {"warnings": [OVERFIT, "collapsed: 0 of 10 latent dimensions active"]}
    box = departures_section([CRASHED], results, "paper")
    flagged = re.findall(r"<li data-flag='generator-warning' data-env='racing'>(.*?)</li>", box)
    assert len(flagged) == 2 and "NLL 207.1 vs 177.5" in flagged[0] and "collapsed" in flagged[1]
    cause = likely_cause(CRASHED, results)
    assert "the generator failed its own gate (overfit)" in cause and "(collapsed)" in cause and "real difference" not in cause
    # a generator the gate rejected and the run used anyway says why (the gate's recorded waiver)
    results["racing"]["phases"]["generator"]["outputs"]["gate"] = {"verdict": "waived", "waiver": "expected at the tiny preset's toy budgets"}
    box = departures_section([CRASHED], results, "tiny")
    assert "collapsed: 0 of 10 latent dimensions active (used anyway: expected at the tiny preset&#x27;s toy budgets)" in box
