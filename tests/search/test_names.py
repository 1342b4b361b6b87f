"""A stored campaign in words (``search.names.describe_campaign``), from records as the quick run stored them."""

from __future__ import annotations

import pytest

from worldagent.search.names import describe_campaign
from worldagent.store import Campaign

AGENT = {"kind": "worldagent", "path": "runs/quick/racing/agent/policy", "sha256": "2514"}
SEARCH = {"agent": AGENT, "bound": 3.0, "dim": 10, "popsize": 21, "random_batch": 21, "sigma0": 1.0}
GRID = {"cells": [10, 10], "descriptors": ["total_curvature", "sharpest_corner"], "ranges": [[7.5, 20.7], [1.4, 2.9]]}
DIFF = {"a": {"kind": "scripted", "path": "homing"}, "b": {"kind": "worldagent", "path": "runs/b/policy"}}


def record(name, objective, maximize, optimiser, budget, seed, config) -> Campaign:
    return Campaign(1, name, "racing", objective, maximize, optimiser, budget, seed, config)


@pytest.mark.parametrize(
    "campaign, words",
    [
        (record("cmaes-min-return-s0", "return", False, "cmaes", 420, 0, SEARCH), "CMA-ES minimising return, 420 evaluations, seed 0"),
        (
            record("cmaes-max-group_reward-s0", "group_reward", True, "cmaes", 105, 0, SEARCH),
            "CMA-ES maximising group_reward, 105 evaluations, seed 0",
        ),
        (record("compare-bo-min-return-s1", "return", False, "bo", 42, 1, SEARCH), "Bayesian optimisation minimising return, 42 evaluations, seed 1"),
        (record("random-return-s0", "return", True, "random", 1000, 0, SEARCH), "Random worlds G(z) scored on return, 1,000 worlds, seed 0"),
        (
            record("atlas-min-return-s0", "return", False, "cma-me", 420, 0, {**SEARCH, "atlas": {"batch": 7, "grid": GRID}}),
            "Atlas (CMA-ME) minimising return over total_curvature × sharpest_corner, 420 evaluations, seed 0",
        ),
        (
            record(
                "failure-is-crash_rate>0.5-s0",
                "margin",
                True,
                "is",
                1250,
                0,
                {"agent": AGENT, "event": "crash_rate > 0.5", "worlds": 1000, "pilot": 250},
            ),
            "Failure rate of crash_rate > 0.5 by importance sampling, 1,000 worlds, seed 0",
        ),
        (
            record("failure-mc-group_reward<50-s0", "margin", True, "mc", 100, 2, {"agent": AGENT, "event": "group_reward < 50", "worlds": 100}),
            "Failure rate of group_reward < 50 by Monte Carlo, 100 worlds, seed 2",
        ),
        (
            record("diff-prior-s0", "return", False, "random", 500, 0, {**SEARCH, "diff": DIFF}),
            "Diff of two agents on 500 random worlds G(z), seed 0",
        ),
        (
            record(
                "diff-campaign-random-return-s0-s0",
                "return",
                False,
                "fixed",
                1000,
                0,
                {"dim": 10, "diff": DIFF, "worlds": {"campaign": "random-return-s0", "store": "s.sqlite"}},
            ),
            "Diff of two agents on the worlds of campaign random-return-s0, 1,000 worlds, seed 0",
        ),
        (
            record("diff-cmaes-min-return-s3", "return", False, "cmaes", 84, 3, {**SEARCH, "diff": DIFF}),
            "Diff search: CMA-ES minimising return(B) − return(A), 84 evaluations, seed 3",
        ),
        (
            record(
                "worlds-prefabs-return-s0",
                "return",
                False,
                "given",
                12,
                0,
                {"dim": 0, "worlds": {"tag": "prefabs", "count": 12, "fingerprint": "ab"}},
            ),
            "Given worlds prefabs scored on return, 12 worlds, seed 0",
        ),
    ],
)
def test_each_kind_of_campaign_reads_in_words(campaign, words):
    assert describe_campaign(campaign, campaign.name) == words


def test_the_words_come_from_the_record_not_the_name():
    renamed = record("my-own-name", "crashed", True, "cmaes", 10, 4, SEARCH)  # `worldagent search --name` any name
    assert describe_campaign(renamed, renamed.name) == "CMA-ES maximising crashed, 10 evaluations, seed 4"


def test_a_campaign_without_a_record_is_its_id():
    assert describe_campaign(None, "cmaes-min-return-s0") == "cmaes-min-return-s0"
