"""Replayed episodes are the evaluator's episodes, with the agents' positions kept."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from worldagent.agents.loaders import scripted_policy
from worldagent.agents.policy import Policy
from worldagent.envs import registry
from worldagent.envs.harvest import Harvest, generate_maps
from worldagent.envs.racing.env import ParticleRacing
from worldagent.envs.racing.tracks import generate_tracks
from worldagent.errors import WorldagentError
from worldagent.evaluation.local import episode_keys, evaluate
from worldagent.evaluation.trajectories import replay, scored_keys
from worldagent.search.objectives import LatentObjective, Objective

RACING = ParticleRacing()
RACING_SPEC, HARVEST_SPEC = registry.get("racing"), registry.get("harvest")


def random_racing_policy():
    return Policy(None, lambda params, obs, key, state=None: jax.random.randint(key, (), 0, 4), "random")


def one(worlds, b):
    return jax.tree_util.tree_map(lambda leaf: leaf[b], worlds)


def test_racing_replays_are_the_evaluated_episodes():
    worlds = generate_tracks(np.arange(3))
    policy = random_racing_policy()  # stochastic: only the same keys give the same episodes
    metrics = evaluate(RACING, policy, worlds, 4, jax.random.key(7))
    keys = episode_keys(jax.random.key(7), 3, 4)
    episodes = replay(RACING_SPEC, RACING, policy, one(worlds, 2), keys[2])
    np.testing.assert_allclose(episodes.metrics["return"], metrics["return"][2], atol=1e-4)
    np.testing.assert_array_equal(episodes.metrics["crashed"], metrics["crashed"][2])
    np.testing.assert_array_equal(episodes.steps, metrics["steps"][2])
    assert episodes.positions.shape == (4, 301, 2) and episodes.present.all()
    np.testing.assert_allclose(episodes.positions[:, 0], np.broadcast_to(np.asarray(worlds.centreline[2, 0]), (4, 2)))
    for e in range(4):
        path = episodes.path(e)
        assert len(path) == metrics["steps"][2, e] + 1
        np.testing.assert_array_equal(episodes.positions[e, len(path) - 1 :], np.broadcast_to(path[-1], (301 - len(path) + 1, 2)))  # frozen


def test_the_keys_of_a_scored_world_replay_its_stored_episodes(racing_generator):
    objective = LatentObjective(Objective("racing", "return", False), RACING, random_racing_policy(), racing_generator, repeats=3)
    z = np.asarray(jax.random.normal(jax.random.key(1), (2, racing_generator.latent_dim)))
    outcomes = objective(z, np.array([101, 202]))
    world = RACING_SPEC.world_from_arrays({name: np.asarray(value) for name, value in vars(outcomes[1].world).items()})
    episodes = replay(RACING_SPEC, RACING, random_racing_policy(), world, scored_keys(202, 3))
    np.testing.assert_allclose(episodes.metrics["return"], [e["return"] for e in outcomes[1].episodes], atol=1e-4)
    assert episodes.metrics["crashed"].tolist() == [e["crashed"] for e in outcomes[1].episodes]


@pytest.mark.integration
def test_harvest_replays_keep_every_agents_cell():
    env = Harvest()
    maps = generate_maps(np.arange(2))
    metrics = evaluate(env, scripted_policy(HARVEST_SPEC, "random"), maps, 2, jax.random.key(3))
    episodes = replay(HARVEST_SPEC, env, scripted_policy(HARVEST_SPEC, "random"), one(maps, 1), episode_keys(jax.random.key(3), 2, 2)[1])
    np.testing.assert_allclose(episodes.metrics["group_reward"], metrics["group_reward"][1])
    assert episodes.positions.shape == (2, 1001, 4, 2) and episodes.present.shape == (2, 1001, 4)
    assert episodes.positions.min() >= 0 and episodes.positions.max() < 25
    walls = np.asarray(maps.walls[1])
    assert not walls[episodes.positions[..., 0], episodes.positions[..., 1]].any()  # never inside a wall
    moves = np.abs(np.diff(episodes.positions, axis=1)).sum(axis=-1)
    assert moves.max() <= 1  # one cell per step (no tagging: nobody is sent back to a corner)


def test_bad_input_is_refused():
    world = one(generate_tracks(np.arange(1)), 0)
    with pytest.raises(WorldagentError, match="1-d array"):
        replay(RACING_SPEC, RACING, scripted_policy(RACING_SPEC, "driver"), world, jax.random.key(0))
    with pytest.raises(WorldagentError, match="without its world"):
        RACING_SPEC.world_from_arrays(None)
