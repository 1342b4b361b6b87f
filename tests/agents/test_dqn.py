"""Independent DQN on Resource Harvest: learning, saving, resuming, refusing bad input (tiny budgets)."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from worldagent.agents import replay as replay_lib
from worldagent.agents.distributions import WorldPool
from worldagent.agents.dqn import DQNConfig, make_act, make_train, make_trainer
from worldagent.agents.dqn_run import evaluate, load_agents, save_agents, train_harvest
from worldagent.agents.policy import load_policy
from worldagent.envs.harvest.policies import random_act
from worldagent.envs.harvest.world import HarvestMap
from worldagent.errors import WorldagentError

TINY_MAP = """
.........
.........
..AAAAA..
..AAAAA..
..AA.AA..
..AAAAA..
..AAAAA..
.........
.........
"""

# Small window and short episodes: the tiny map is in view from every corner.
TINY = DQNConfig(
    num_episodes=16 * 8,
    episode_length=50,
    num_envs=16,
    view_size=9,
    view_behind=2,
    hidden_sizes=(32, 32),
    batch_size=64,
    buffer_size=8_000,
    learning_starts=200,
    target_update_every=100,
    learning_rate=1e-3,
    epsilon_decay_episodes=16 * 4,
    checkpoint_every=4,
    seed=0,
)


@pytest.fixture(scope="module")
def tiny_pool():
    world = HarvestMap.from_str(TINY_MAP)
    return WorldPool.create(jax.tree_util.tree_map(lambda x: np.asarray(x)[None], world))


@pytest.fixture(scope="module")
def trained(tiny_pool, tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    return train_harvest(TINY, tiny_pool, out, progress=False), out


def test_pack_planes_round_trip():
    obs = jax.random.bernoulli(jax.random.key(0), 0.3, (3, 9, 9, 4)).astype(jnp.uint8)
    assert jnp.array_equal(replay_lib.unpack_planes(replay_lib.pack_planes(obs), 4), obs)


def test_replay_samples_stored_transitions_with_their_successor():
    replay = replay_lib.create(4, 2, 1, (1, 1, 4))
    add = jax.jit(replay_lib.add)
    for t in range(6):  # wraps around: slices hold steps 2..5
        obs = jnp.asarray(np.eye(4, dtype=np.uint8)[t % 4][None, None, None, None].repeat(2, 0))
        replay = add(replay, obs, jnp.full((2, 1), t), jnp.full((2, 1), float(t)), jnp.array([t == 3, False]))
    batch = jax.jit(replay_lib.sample, static_argnums=(3, 4))(jax.random.key(1), replay, jnp.int32(0), 256, 4)
    steps = np.asarray(batch["action"])
    assert set(steps.tolist()) == {2, 3, 4}  # the newest step (5) has no successor yet
    assert np.array_equal(np.asarray(batch["reward"]), steps.astype(float))
    assert np.array_equal(np.argmax(np.asarray(batch["next_obs"])[:, 0, 0], -1), (steps + 1) % 4)


def test_dqn_beats_random_on_tiny_map(trained, tiny_pool):
    result, _ = trained
    worlds = tiny_pool.worlds
    key = jax.random.key(7)
    learned = evaluate(key, make_act(TINY), result.params, worlds, TINY, repeats=16)["group_reward"].mean()
    random = evaluate(key, random_act, None, worlds, TINY, repeats=16)["group_reward"].mean()
    assert learned > 2.0 * random, (float(learned), float(random))  # measured: about 26.5 vs 10-12


def test_saved_agents_reload_and_act_identically(trained, tmp_path):
    result, out = trained
    act, params, config = load_agents(out / "agents", epsilon=0.0)
    assert config == TINY
    obs = jax.random.bernoulli(jax.random.key(3), 0.2, (5, 4, 9, 9, 4)).astype(jnp.uint8)
    key = jax.random.key(4)
    assert jnp.array_equal(act(params, obs, key), make_act(TINY, 0.0)(result.params, obs, key))
    act_eps, _, _ = load_agents(out / "agents")  # epsilon-greedy with the config's act_epsilon: same key, same actions
    assert jnp.array_equal(act_eps(params, obs, key), make_act(TINY)(result.params, obs, key))
    assert act(params, obs[0], key).shape == (4,)
    # The generic loader (policy.load_policy) gives the same agents when asked to be greedy.
    saved = load_policy(out / "agents", env="harvest", algorithm="dqn", greedy=True)
    assert saved.num_agents == 4 and jnp.array_equal(saved.policy(obs[0], key), act(params, obs[0], key))


def test_run_directory_contents(trained):
    result, out = trained
    assert len(result.history) == TINY.num_chunks and result.env_steps == TINY.num_chunks * 16 * 50
    lines = (out / "curve.csv").read_text().splitlines()
    assert lines[0].startswith("chunk,episodes") and len(lines) == TINY.num_chunks + 1
    assert (out / "curve.png").stat().st_size > 0
    assert json.loads((out / "config.json").read_text())["num_episodes"] == TINY.num_episodes


def test_resume_continues_from_checkpoint(tiny_pool, tmp_path):
    short = dataclasses.replace(TINY, num_episodes=16 * 4, checkpoint_every=2)  # compiled once, shared with `trained`
    full = train_harvest(short, tiny_pool, tmp_path / "a", progress=False)
    # A run killed after its first checkpoint: keep only that checkpoint's files.
    partial = dataclasses.replace(short, num_episodes=16 * 2)
    train_harvest(partial, tiny_pool, tmp_path / "b", progress=False)
    config = json.loads((tmp_path / "b" / "config.json").read_text())
    config["num_episodes"] = short.num_episodes
    (tmp_path / "b" / "config.json").write_text(json.dumps(config))
    resumed = train_harvest(short, tiny_pool, tmp_path / "b", progress=False)
    assert resumed.resumed_chunks == 2 and len(resumed.history) == 4
    for a, b in zip(jax.tree_util.tree_leaves(full.params), jax.tree_util.tree_leaves(resumed.params)):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)


def test_make_train_is_one_jitted_run(tiny_pool):
    config = dataclasses.replace(TINY, num_episodes=32)
    state, stats = make_train(config, tiny_pool)(jax.random.key(0))
    assert stats["group_reward"].shape == (2, 16) and int(state.steps) == 100 and int(state.updates) > 0


@pytest.mark.parametrize(
    "change, message",
    [
        ({"num_episodes": 0}, "num_episodes"),
        ({"num_envs": -1}, "num_envs"),
        ({"tagger": 4}, "tagger"),
        ({"hidden_sizes": ()}, "hidden_sizes"),
        ({"gamma": 1.0}, "gamma"),
        ({"epsilon_end": 2.0}, "epsilon"),
        ({"view_size": 4}, "view_size"),
    ],
)
def test_bad_settings_are_refused(change, message):
    with pytest.raises(WorldagentError, match=message):
        make_trainer(dataclasses.replace(TINY, **change))


def test_unknown_algorithm_and_bad_distribution_are_refused(tiny_pool, tmp_path):
    with pytest.raises(WorldagentError, match="unknown harvest algorithm 'ppo'"):
        train_harvest(TINY, tiny_pool, tmp_path, algo="ppo")
    with pytest.raises(WorldagentError, match="sample"):
        train_harvest(TINY, object(), tmp_path)


def test_checkpoint_of_another_architecture_is_refused(trained, tiny_pool, tmp_path):
    result, out = trained
    # Agents saved with one architecture, described as another.
    save_agents(tmp_path / "agents", result.params, TINY)
    meta = json.loads((tmp_path / "agents" / "policy.json").read_text())
    meta["network"]["config"]["hidden"] = [64, 64]
    (tmp_path / "agents" / "policy.json").write_text(json.dumps(meta))
    with pytest.raises(WorldagentError, match="another network"):
        load_agents(tmp_path / "agents")
    meta["network"]["config"]["hidden"] = [32, 32]
    meta["training"]["hidden_sizes"] = [16]
    (tmp_path / "agents" / "policy.json").write_text(json.dumps(meta))
    with pytest.raises(WorldagentError, match="another architecture"):
        load_agents(tmp_path / "agents")
    # Resuming a run directory with other settings.
    with pytest.raises(WorldagentError, match="other settings.*hidden_sizes"):
        train_harvest(dataclasses.replace(TINY, hidden_sizes=(16,)), tiny_pool, out, progress=False)
    with pytest.raises(WorldagentError, match="no saved policy"):
        load_agents(tmp_path / "missing")


def test_load_policy_acts_with_the_recorded_exploration_rate(tmp_path):
    """Saved DQN agents act epsilon-greedily as trained (greedy memoryless agents get stuck)."""
    import jax
    import numpy as np

    from worldagent.agents.dqn import DQNConfig, init_params
    from worldagent.agents.dqn_run import save_agents
    from worldagent.agents.policy import load_policy

    config = DQNConfig(act_epsilon=0.5)
    params = init_params(jax.random.key(0), config)
    save_agents(tmp_path, params, config, extra={"act_epsilon": 0.5})
    obs = np.zeros((4, config.view_size, config.view_size, 4), np.uint8)
    keys = jax.random.split(jax.random.key(1), 400)
    explorer = load_policy(tmp_path).policy
    greedy = load_policy(tmp_path, greedy=True).policy
    acted = np.stack([np.asarray(explorer(obs, k)) for k in keys[:200]])
    best = np.asarray(greedy(obs, keys[0]))
    assert all(np.array_equal(np.asarray(greedy(obs, k)), best) for k in keys[:20])
    differs = (acted != best).mean()
    assert 0.3 < differs < 0.6  # ~0.5 · 7/8 of actions are random and not the argmax
