"""``Pictures.marks``: what the explorer's animation draws besides the agents, step by step.

Harvest's play carries its apples (eaten, regrown) and its TAG beams at every step; racing's
carries none and is replayed with its own trace (the program every other replay compiles).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from worldagent.envs import registry
from worldagent.explore.episodes import episodes_payload, replay_marked

STEPS = 40  # a short harvest episode: compiles and plays in seconds
EVERY = 5  # agent 0 fires its beam at steps 1, 6, 11, ...
SIZE = 190  # 10 px per cell of the 19-cell map


@pytest.fixture(scope="module")
def harvest_play():
    """Two episodes of a 40-step harvest where agents 1-3 walk to apples and agent 0 fires every 5 steps."""
    from worldagent.agents.policy import Policy
    from worldagent.envs.harvest.env import TAG, make_params
    from worldagent.envs.harvest.policies import greedy_policy

    spec = registry.get("harvest")
    env, _ = spec.make_env({"tagger": (0,)})
    params = make_params(can_tag=[True, False, False, False], max_steps=STEPS)
    greedy = greedy_policy(env)

    def act(policy_params, obs, key, state):
        chosen = greedy(policy_params, obs, key)
        return chosen.at[0].set(jnp.where(state.time % EVERY == 0, TAG, chosen[0]))

    policy = Policy(None, act, "greedy-tagger", privileged=True)
    world = jax.tree_util.tree_map(lambda leaf: np.asarray(leaf)[0], spec.generate(np.array([3], np.int64)))
    keys = jax.random.split(jax.random.key(0), 2)
    played, marks = replay_marked(spec, env, policy, world, keys, params)
    return {
        "spec": spec,
        "world": world,
        "played": played,
        "marks": marks,
        "payload": episodes_payload(spec, world, played, params, SIZE, marks),
        "replay": (env, policy, world, keys, params),
    }


def shown_at(changes: list, step: int) -> set:
    """The marks of one kind there at ``step``, replaying the payload's changes as the page does."""
    there: dict = {}
    for t, appeared, vanished in changes:
        if t > step:
            break
        for xy in vanished:
            there[tuple(xy)] -= 1
        for xy in appeared:
            there[tuple(xy)] = there.get(tuple(xy), 0) + 1
    return {xy for xy, count in there.items() if count > 0}


def cell_pixels(cells) -> set:
    return {((col + 0.5) * SIZE / 19, (row + 0.5) * SIZE / 19) for row, col in cells}


def test_harvest_play_carries_the_apples_at_every_step(harvest_play):
    spec, world, played, payload = (harvest_play[k] for k in ("spec", "world", "played", "payload"))
    assert set(payload["marks"]) == {"apple", "beam", "tagged"} and payload["marks"]["apple"]["shape"] == "dot"
    sites = cell_pixels(np.argwhere(np.asarray(world.apples)))
    for e, episode in enumerate(payload["episodes"]):
        apples = episode["marks"]["apple"]
        assert shown_at(apples, 0) == sites  # the map's apples at the start
        eaten = sum(len(vanished) for _, _, vanished in apples)
        assert eaten > 0 and eaten == played.metrics["returns"][e].sum()  # an apple goes only when eaten, +1 each
        assert shown_at(apples, episode["steps"]) != sites
        assert all(shown_at(apples, t) <= sites for t in range(0, episode["steps"] + 1, 7))  # regrowth only on apple sites
        path = np.asarray(spec.pictures.locate(played.path(e), world, SIZE)).round(1)
        np.testing.assert_array_equal(np.asarray(episode["path"]), path)


def test_harvest_play_marks_the_steps_where_a_beam_fires(harvest_play):
    played, marks, payload = (harvest_play[k] for k in ("played", "marks", "payload"))
    fired = set(range(1, STEPS + 1, EVERY))
    for e, episode in enumerate(payload["episodes"]):
        beams = episode["marks"]["beam"]
        lit = {t for t in range(episode["steps"] + 1) if shown_at(beams, t)}
        assert lit and lit <= fired  # a beam shows at agent 0's firing steps (unless it faces a wall) and never at another
        for t in lit:
            where, shown = np.asarray(marks["beam"][0][e, t]), np.asarray(marks["beam"][1][e, t])
            assert shown_at(beams, t) == cell_pixels(where[shown])
            x, y = episode["path"][t][0]  # the beam starts next to agent 0 (its centre lane ahead, or a side lane's first cell)
            assert min(abs(bx - x) + abs(by - y) for bx, by in shown_at(beams, t)) in (pytest.approx(SIZE / 19), pytest.approx(2 * SIZE / 19))
        assert not shown_at(episode["marks"]["tagged"], episode["steps"])  # agent 0 never hits anyone here: nobody is out
        assert played.present[e].all()


def test_harvest_marks_do_not_change_the_episodes(harvest_play):
    """The marks ride in the trace: the agents' positions and metrics are those ``replay`` gives."""
    from worldagent.evaluation.trajectories import replay

    spec, played = harvest_play["spec"], harvest_play["played"]
    again = replay(spec, *harvest_play["replay"])
    np.testing.assert_array_equal(again.positions, played.positions)
    np.testing.assert_array_equal(again.present, played.present)
    np.testing.assert_array_equal(again.steps, played.steps)
    np.testing.assert_array_equal(again.metrics["returns"], played.metrics["returns"])


def test_racing_has_no_marks_and_replays_with_its_own_trace(monkeypatch):
    from worldagent.evaluation import trajectories

    racing = registry.get("racing")
    assert racing.pictures.marks is None
    seen = []
    monkeypatch.setattr(trajectories, "replay", lambda spec, *args: seen.append(spec) or "episodes")
    assert replay_marked(racing, None, None, None, None, None) == ("episodes", {})
    assert seen == [racing]  # its own spec and trace: the same compiled program as every other replay
    world = jax.tree_util.tree_map(lambda leaf: np.asarray(leaf)[0], racing.generate(np.array([0], np.int64)))
    played = trajectories.Episodes(np.zeros((1, 3, 2), np.float32), np.ones((1, 3), bool), np.array([2]), {"return": np.zeros(1)})
    payload = episodes_payload(racing, world, played, racing.make_env()[1], 96)
    assert payload["marks"] is None and "marks" not in payload["episodes"][0]


def test_a_tagged_out_agent_is_marked_where_it_was_hit():
    """On an open 9x9 map agent 0 fires every step; agent 2 walks north from its corner into the beam."""
    from worldagent.agents.policy import Policy
    from worldagent.envs.harvest.env import FORWARD, NOOP, TAG, make_params
    from worldagent.envs.harvest.world import HarvestMap

    spec = registry.get("harvest")
    env, _ = spec.make_env({"tagger": (0,)})
    params = make_params(can_tag=[True, False, False, False], max_steps=STEPS)
    world = HarvestMap.from_str("\n".join(["........."] * 9))
    policy = Policy(None, lambda p, obs, key, state: jnp.array([TAG, NOOP, FORWARD, NOOP], jnp.int32), "tag-walk", privileged=True)
    played, marks = replay_marked(spec, env, policy, world, jax.random.split(jax.random.key(1), 1), params)
    episode = episodes_payload(spec, world, played, params, 90, marks)["episodes"][0]
    out = [t for t in range(episode["steps"] + 1) if not episode["present"][t][2]]
    assert len(out) >= 25  # hit at least once, out for 25 steps
    for t in range(episode["steps"] + 1):
        assert shown_at(episode["marks"]["tagged"], t) == ({(5.0, 55.0)} if t in out else set())  # cell (5, 0), 10 px a cell
    assert shown_at(episode["marks"]["beam"], out[0])  # the beam that hit it


def test_agents_keep_the_colours_of_the_envs_own_pictures():
    """The explorer draws each agent in the colour the env's picture of episodes (and so the report's figures) gives it."""
    from worldagent.envs.harvest import render
    from worldagent.explore.episodes import agent_colours

    harvest = agent_colours(registry.get("harvest").pictures)
    assert len(harvest) == len(render.AGENT_COLOURS) == 4
    for css, rgb in zip(harvest, render.AGENT_COLOURS, strict=True):  # the colours draw_episodes draws them in
        assert [int(css[k : k + 2], 16) for k in (1, 3, 5)] == [round(255 * v) for v in rgb]
    assert agent_colours(registry.get("racing").pictures) == []  # one agent: each episode its own colour (the page's)
