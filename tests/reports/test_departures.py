"""The report's first box: where a run departs from the paper, each gap's possible causes (only what the run's own record
shows: settings unlike the paper preset, the generator's gate warnings) and section; one seed said as such."""

from __future__ import annotations

import re

import pytest

from worldagent.reports.departures import departures, departures_section, differs, likely_cause, paper_config, run_differences
from worldagent.reports.results import Headline, influence_headlines
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


def harvest_results(seeds=(0,)):
    """What ``results.env_results`` gives for a quick-like harvest run (only what the box reads)."""
    summary = {
        "equality": {"default": {"mean": 0.671}, "influenced": {"mean": 0.659}},
        "conflict": {"default": {"mean": 0.071}, "influenced": {"mean": 0.05}},
        "group_reward": {"default": {"mean": 150.0}, "influenced": {"mean": 160.0}},
    }
    phases = {
        "agent": {"status": "done", "config": {"episodes": 1000}},
        "random": {"status": "done", "config": {"worlds": 200, "repeats": 8}},
        "strategic": {"status": "done", "config": {"budget": 105, "repeats": 8}},
        "influence": {"status": "done", "config": {"seeds": list(seeds), "episodes": 1000, "eval_worlds": 100, "repeats": 8}},
    }
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
    """A racing run whose every phase recorded the paper preset's config, with ``{phase: {field: value}}`` changed."""
    phases = {phase: {"status": "done", "config": {**paper_config("racing", phase), **changes.get(phase, {})}} for phase in PHASES}
    return {"racing": {"phases": phases}}


def test_a_run_with_the_paper_settings_may_call_a_gap_real():
    results = racing_as_paper()
    assert run_differences("racing", results["racing"]) == []
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


def test_an_omitted_setting_is_its_default_and_repeats_and_repair_count():
    """The quick preset records no options for racing (route, the default) where the paper's records rays; repeats and the repair
    are compared too."""
    phases = racing_as_paper(random={"repeats": 2})["racing"]["phases"]
    phases["agent"]["config"].pop("options")
    phases["generator"]["config"]["repair"] = "open"  # reproduce --repair open; the paper preset records none: its default, nearest
    found = {(d.phase, d.name): (d.ours, d.paper) for d in run_differences("racing", {"phases": phases})}
    assert found == {("agent", "options.observation"): ("route", "rays"), ("random", "repeats"): (2, 8), ("generator", "repair"): ("open", "nearest")}


def test_a_phase_without_recorded_settings_leaves_the_gap_unexplained():
    results = racing_as_paper()
    results["racing"]["phases"]["generator"]["config"] = {}
    cause = likely_cause(CRASHED, results)
    assert cause.startswith("unexplained: the generator phase recorded no settings") and "real difference" not in cause


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
