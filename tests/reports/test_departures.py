"""The report's first box: where a run departs from the paper, each gap's likely cause and section; one seed said as such."""

from __future__ import annotations

import re

import pytest

from worldagent.reports.departures import departures, departures_section, differs
from worldagent.reports.results import Headline, influence_headlines


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
    assert random.anchor == "random" and "1,000 training episodes (the paper's: 5,000)" in random.cause and "best single episode" in random.cause
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
