"""Selections: the grammar, its one-line errors, masks over per-world means, and select_worlds."""

from __future__ import annotations

import numpy as np
import pytest

from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.events import parse_selection
from worldagent.influence.worlds import search_direction, select_worlds
from worldagent.store import Evaluation, RunStore


def evaluation(episodes: list[dict]) -> Evaluation:
    return Evaluation("c", 0, 0, np.zeros(2), 0.0, episodes, 0.0, 0.0)


def racing_episodes(crashed, progress, ret=-100.0):
    return [
        {"return": ret, "normalised_return": 0.5, "crashed": c, "lap_completed": 0, "progress": p, "steps": 10} for c, p in zip(crashed, progress)
    ]


@pytest.mark.parametrize(
    ("text", "metrics", "ops", "numbers"),
    [
        ("crashed > 0.5", ("crashed",), (">",), (0.5,)),
        ("crash_rate>0.5", ("crashed",), (">",), (0.5,)),
        ("  lap_rate   <=   .25  ", ("lap_completed",), ("<=",), (0.25,)),
        ("return >= -120.5 and crashed == 0", ("return", "crashed"), (">=", "=="), (-120.5, 0.0)),
        ("reward != 1e2 AND progress < 3", ("return", "progress"), ("!=", "<"), (100.0, 3.0)),
        ("normalised_return>-1and steps<+300", ("normalised_return", "steps"), (">", "<"), (-1.0, 300.0)),
    ],
)
def test_documented_forms_parse(text, metrics, ops, numbers):
    selection = parse_selection(text, "racing")
    assert tuple(c.metric for c in selection.clauses) == metrics
    assert tuple(c.op for c in selection.clauses) == ops
    assert tuple(c.number for c in selection.clauses) == numbers
    assert selection.text == text.strip()


def test_aliases_resolve_per_env_and_describe_spells_them_out():
    assert parse_selection("reward > 3", "harvest").clauses[0].metric == "group_reward"
    assert parse_selection("reward > 3").clauses[0].metric is None  # resolved when applied
    assert parse_selection("reward > 3").resolve("racing").clauses[0].metric == "return"
    assert parse_selection("crash_rate > 0.5 and conflict == 0").describe() == "crash_rate (crashed) > 0.5 and conflict == 0"
    with pytest.raises(WorldagentError, match="unknown harvest metric 'crash_rate'"):
        parse_selection("crash_rate > 0.5", "harvest")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("__import__('os')", "unexpected '\\('"),
        ("crashed >", "missing number after 'crashed >'"),
        ("foo > 1", "unknown racing metric 'foo'.*use one of: return, normalised_return, crashed"),
        ("crashed => 1", "bad operator '=>'"),
        ("crashed = 1", "bad operator '='"),
        ("1 > crashed", "expected a metric name at character 1, got '1'"),
        ("", "the selection is empty"),
        ("   ", "the selection is empty"),
        ("crashed > 0.5 or steps > 3", "unexpected 'or'.*join clauses with 'and'"),
        ("crashed > 0.5 1", "unexpected '1'"),
        ("crashed > 0.5 and", "ends with 'and'"),
        ("crashed 0.5", "expected an operator"),
        ("crashed > nan", "missing number"),
        ("crashed > 1e999", "not finite"),
        ("crashed > 0.5; import os", "unexpected ';'"),
    ],
)
def test_junk_is_refused_with_one_line_naming_the_fix(text, message):
    with pytest.raises(WorldagentError, match=message) as error:
        parse_selection(text, "racing")
    assert "\n" not in str(error.value)


def test_mask_matches_a_hand_computation():
    evaluations = [
        evaluation(racing_episodes([1, 1, 0, 1], [0.1, 0.2, 0.3, 0.4])),  # crash rate 0.75, progress 0.25
        evaluation(racing_episodes([1, 0, 0, 0], [0.9, 0.9, 0.9, 0.9])),  # 0.25, 0.9
        evaluation(racing_episodes([1, 1, 1, 1], [0.0, 0.0, 0.0, 0.1])),  # 1.0, 0.025
        evaluation(racing_episodes([0, 1, 0, 1], [0.5, 0.5, 0.5, 0.5])),  # 0.5, 0.5
    ]
    crash = np.array([0.75, 0.25, 1.0, 0.5])
    progress = np.array([0.25, 0.9, 0.025, 0.5])
    selection = parse_selection("crash_rate > 0.5", "racing")
    np.testing.assert_array_equal(selection.mask(evaluations), crash > 0.5)
    np.testing.assert_allclose(selection.world_means(evaluations)["crashed"], crash)
    both = parse_selection("crash_rate >= 0.5 and progress < 0.3")
    np.testing.assert_array_equal(both.mask(evaluations), (crash >= 0.5) & (progress < 0.3))
    np.testing.assert_array_equal(parse_selection("crashed == 0.5").mask(evaluations), crash == 0.5)
    np.testing.assert_array_equal(parse_selection("crashed != 0.5").mask(evaluations), crash != 0.5)
    np.testing.assert_array_equal(parse_selection("reward <= -100").mask(evaluations), [True] * 4)  # env inferred: racing


def test_search_direction_follows_the_first_clause():
    assert search_direction(parse_selection("crash_rate > 0.5", "racing"), np.array([0.1]))
    assert not search_direction(parse_selection("conflict < 1", "harvest"), np.array([3.0]))
    assert not search_direction(parse_selection("conflict == 0", "harvest"), np.array([0.5, 2.0]))  # toward 0 from above
    assert search_direction(parse_selection("equality == 1", "harvest"), np.array([0.3]))


def harvest_store(tmp_path, conflicts: list[list[float]]) -> RunStore:
    """A store with one campaign of harvest worlds whose episodes have the given conflicts."""
    maps = registry.get("harvest").generate(np.arange(len(conflicts)))
    store = RunStore(tmp_path)
    campaign = store.open_campaign("influence-candidates", "harvest", "conflict", False, "random", len(conflicts), 0, {}, False)
    for slot, values in enumerate(conflicts):
        world = type(maps)(walls=maps.walls[slot], apples=maps.apples[slot])
        episodes = [
            {"group_reward": 1.0, "conflict": c, "equality": 0.5, "sustainability": 3.0, "peace": 4.0, "returns": [1, 0, 0, 0]} for c in values
        ]
        store.add(campaign, 0, slot, np.full(3, slot, float), float(np.mean(values)), episodes, 0.0, world)
    return store, maps


def test_select_worlds_keeps_the_matching_worlds_with_their_latents(tmp_path):
    store, maps = harvest_store(tmp_path, [[0, 0], [3, 0], [0, 0], [1, 5]])
    with store:
        worlds, latents, values = select_worlds(store, ["influence-candidates"], "conflict == 0", "harvest")
    np.testing.assert_array_equal(latents[:, 0], [0, 2])
    np.testing.assert_array_equal(worlds.walls, np.asarray(maps.walls)[[0, 2]])
    np.testing.assert_array_equal(worlds.apples, np.asarray(maps.apples)[[0, 2]])
    assert list(values) == ["conflict"] and np.allclose(values["conflict"], 0)


def test_select_worlds_keeps_each_distinct_world_once(tmp_path):
    """Latents that decode to the same world count once: the new distribution is over worlds, not visits."""
    maps = registry.get("harvest").generate(np.arange(2))
    store = RunStore(tmp_path)
    campaign = store.open_campaign("influence-candidates", "harvest", "conflict", False, "random", 4, 0, {}, False)
    for slot, which in enumerate([0, 1, 0, 0]):  # world 0 visited three times
        world = type(maps)(walls=maps.walls[which], apples=maps.apples[which])
        episodes = [{"group_reward": 1.0, "conflict": 0.0, "equality": 0.5, "sustainability": 3.0, "peace": 4.0, "returns": [1, 0, 0, 0]}]
        store.add(campaign, 0, slot, np.full(3, slot, float), 1.0, episodes, 0.0, world)
    with store:
        worlds, latents, _ = select_worlds(store, ["influence-candidates"], "conflict == 0", "harvest")
    np.testing.assert_array_equal(latents[:, 0], [0, 1])  # the first visit of each world
    np.testing.assert_array_equal(worlds.walls, np.asarray(maps.walls)[[0, 1]])


def test_empty_selection_says_how_many_worlds_were_tried_and_each_metrics_range(tmp_path):
    store, _ = harvest_store(tmp_path, [[1, 2], [3, 4], [5, 6]])
    with store, pytest.raises(WorldagentError) as error:
        select_worlds(store, ["influence-candidates"], "conflict == 0 and equality > 0.1", "harvest")
    message = str(error.value)
    assert "none of the 3 worlds tried" in message
    assert "conflict ranged 1.5 to 5.5" in message and "equality ranged 0.5 to 0.5" in message
    assert "\n" not in message
