"""The report's words for the world's share (reports.noise): the random-evaluation paragraph and the departures line."""

from __future__ import annotations

import html
import re

import numpy as np

from worldagent.analysis.noise import repeats_for
from worldagent.envs import registry
from worldagent.reports.departures import departures_section
from worldagent.reports.noise import share_note, share_paragraph
from worldagent.reports.results import world_share_summary
from worldagent.store import Evaluation


def racing_like(icc: float, worlds: int = 300, repeats: int = 8) -> list[Evaluation]:
    """Worlds whose return is a world effect plus dice (the world's share ``icc``); an episode crashes below 40."""
    rng = np.random.default_rng(0)
    returns = 50 + 25 * (rng.normal(0, np.sqrt(icc), (worlds, 1)) + rng.normal(0, np.sqrt(1 - icc), (worlds, repeats)))
    episodes = [[{"return": float(r), "crashed": float(r < 40)} for r in row] for row in returns]
    return [Evaluation("random-return-s0", 0, i, np.zeros(2), float(np.mean(row)), e, 0.0, 0.0) for i, (row, e) in enumerate(zip(returns, episodes))]


def test_the_paragraph_gives_both_shares_the_reliability_and_says_luck_below_a_quarter():
    summary = world_share_summary(registry.get("racing"), racing_like(0.1))
    share = summary["metrics"]["return"]
    assert "crashed" in summary["failure"]["event"] and share["icc"] < 0.25
    text = share_paragraph(summary, "return")
    assert f"<span data-share='return'>{share['icc']:.2g} [{share['low']:.2g}, {share['high']:.2g}]</span>" in text
    assert "data-share='failure'" in text and "300 worlds × 8 episodes" in text
    assert f"reliability {share['reliability']:.2g}" in text and "in at least half of theirs" in text
    assert "mostly finds luck" in text and f"{repeats_for(share['icc'])} episodes per world give a score of reliability 0.8" in text
    worldly = share_paragraph(world_share_summary(registry.get("racing"), racing_like(0.8)), "return")
    assert "finds worlds" in worldly and "luck" not in worldly
    assert share_paragraph({}, "return") == ""


def test_the_departures_box_names_each_envs_world_share():
    summary = world_share_summary(registry.get("racing"), racing_like(0.1))
    results = {"racing": {"phases": {}, "random": {"share": summary}}, "harvest": {"phases": {}}}
    box = departures_section([], results, "quick")
    (line,) = re.findall(r"<li data-share-env='racing'>(.*?)</li>", box)
    assert line == html.escape(share_note("racing", summary, "return"))
    assert line.startswith("racing: the world&#x27;s share of return 0.") and "mostly luck" in line
    assert f"of the failure ({html.escape(summary['failure']['event'])})" in line
    assert "data-share-env='harvest'" not in box  # no random campaign: nothing said
    assert "data-share-env" not in departures_section([], {"harvest": {"phases": {}}}, "quick")


def test_the_random_section_says_the_share_of_its_stored_campaign(tmp_path):
    from worldagent.reports.html import random_section
    from worldagent.reports.results import Scale, random_results
    from worldagent.runs import RunLayout

    spec = registry.get("racing")
    evaluations = racing_like(0.1)
    scale = Scale(spec.make_env()[1], None)
    random = random_results(spec, evaluations, "random-return-s0", scale)
    assert random["share"] == world_share_summary(spec, evaluations)
    phases = {"random": {"status": "done", "config": {"repeats": 8}}}
    results = {"racing": {"phases": phases, "metric": "return", "layout": RunLayout(tmp_path, "racing"), "random": random}}
    page = random_section(tmp_path, results)
    assert share_paragraph(random["share"], "return") in page and "<p class='share'>" in page
    one_episode = random_results(
        spec, [Evaluation("r", 0, i, np.zeros(2), 1.0, [{"return": 1.0, "crashed": 0.0}], 0.0, 0.0) for i in range(3)], "r", scale
    )
    assert one_episode["share"] == {}  # one episode per world: no share, no paragraph
