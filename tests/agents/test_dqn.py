"""Independent DQN on a tiny Resource Harvest: learning, saving, resuming, refusing bad input (tiny budgets).

The tiny env (a 9x9 window, 50-step episodes) is registered as its own spec, as a third-party
env would be, so the host driver runs it exactly as it runs harvest.
"""

from __future__ import annotations

import dataclasses
import json

import flax.serialization
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from worldagent.agents import replay as replay_lib
from worldagent.agents import training
from worldagent.agents.algorithms import training_config
from worldagent.agents.distributions import WorldPool
from worldagent.agents.dqn import DQNConfig, epsilon_at, make_train
from worldagent.agents.loaders import load_agent
from worldagent.agents.policy import Policy, network_policy
from worldagent.agents.saved import load_policy, save_policy
from worldagent.envs import registry
from worldagent.envs.core import rollout
from worldagent.envs.harvest.env import Harvest, make_params
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
EPISODE = 50

TINY = DQNConfig(
    num_episodes=16 * 8,
    num_envs=16,
    hidden_sizes=(32, 32),
    batch_size=64,
    buffer_size=8_000,
    learning_starts=200,
    target_update_every=100,
    learning_rate=1e-3,
    epsilon_decay_episodes=16 * 4,
)


def make_tiny(options):
    """Small window and short episodes: the tiny map is in view from every corner."""
    del options
    return Harvest(view_size=9, view_behind=2), make_params(max_steps=EPISODE)


@pytest.fixture(scope="module")
def spec():
    tiny = registry.register(dataclasses.replace(registry.get("harvest"), name="tiny_harvest", make=make_tiny, options=()))
    yield tiny
    registry.unregister("tiny_harvest")


@pytest.fixture(scope="module")
def tiny_pool():
    world = HarvestMap.from_str(TINY_MAP)
    return WorldPool.create(jax.tree_util.tree_map(lambda x: np.asarray(x)[None], world))


@pytest.fixture(scope="module")
def trained(spec, tiny_pool, tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    return training.train(spec, "dqn", TINY, tiny_pool, out, seed=0, progress=False), out


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


def _group_reward(spec, policy, worlds, key, repeats=16):
    env, params = spec.make_env()
    one = lambda k: env.metrics(rollout(env, policy, k, jax.tree_util.tree_map(lambda x: x[0], worlds), params, EPISODE)[0])  # noqa: E731
    return float(jax.jit(jax.vmap(one))(jax.random.split(key, repeats))["group_reward"].mean())


@pytest.mark.integration
def test_dqn_beats_random_on_tiny_map(spec, trained, tiny_pool):
    result, _ = trained
    key = jax.random.key(7)
    learned = _group_reward(spec, result.agent.policy, tiny_pool.worlds, key)  # epsilon-greedy, as trained
    random = _group_reward(spec, Policy(None, lambda p, obs, k, s: random_act(p, obs, k)), tiny_pool.worlds, key)
    assert learned > 2.0 * random, (learned, random)  # measured: about 26.5 vs 10-12


@pytest.mark.integration
def test_saved_agents_reload_and_act_identically(spec, trained):
    result, out = trained
    checkpoint = flax.serialization.msgpack_restore((out / training.CHECKPOINT_FILE).read_bytes())
    params = jax.tree_util.tree_map(jnp.asarray, flax.serialization.from_state_dict(result.agent.params, checkpoint["params"]))
    trained_policy = network_policy(result.agent.module, params, "q_network", greedy=True, num_agents=4)
    loaded = load_agent(spec, str(out), greedy=True)  # the run directory, as `--agent` takes it
    obs = jax.random.bernoulli(jax.random.key(3), 0.2, (4, 9, 9, 4)).astype(jnp.uint8)
    key = jax.random.key(4)
    assert jnp.array_equal(loaded.act(loaded.params, obs, key, None), trained_policy.act(params, obs, key, None))
    explorer = load_policy(out / "policy")  # epsilon-greedy with the config's act_epsilon
    assert explorer.extra["act_epsilon"] == TINY.act_epsilon and explorer.num_agents == 4 and explorer.algorithm == "dqn"


@pytest.mark.integration
def test_run_directory_contents(trained):
    result, out = trained
    assert len(result.curve["group_reward"]) == TINY.num_chunks and result.env_steps == TINY.num_chunks * 16 * EPISODE
    header = (out / "curve.csv").read_text().splitlines()[0].split(",")
    for field in ("update", "episodes", "group_reward", "equality", "conflict", "returns_0", "loss", "q", "epsilon"):
        assert field in header, field
    assert (out / "curve.png").stat().st_size > 0
    run = json.loads((out / "run.json").read_text())
    assert run["config"]["num_episodes"] == TINY.num_episodes and run["env"] == "tiny_harvest" and run["algorithm"] == "dqn"


@pytest.mark.integration
def test_resume_continues_from_checkpoint(spec, tiny_pool, tmp_path):
    short = TINY.with_episodes(16 * 4)  # compiled once, shared with `trained`
    full = training.train(spec, "dqn", short, tiny_pool, tmp_path / "a", progress=False)
    killed = training.train(spec, "dqn", short, tiny_pool, tmp_path / "b", progress=False, stop_after_chunks=2)
    assert killed.episodes == 32
    resumed = training.train(spec, "dqn", short, tiny_pool, tmp_path / "b", progress=False)
    assert resumed.resumed_from_update == 2 and len(resumed.curve["update"]) == 4
    for a, b in zip(jax.tree_util.tree_leaves(full.agent.params), jax.tree_util.tree_leaves(resumed.agent.params)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    with pytest.raises(WorldagentError, match="another config"):
        training.train(spec, "dqn", short.replace(hidden_sizes=(16,)), tiny_pool, tmp_path / "b", progress=False)


def _one_jitted_run(spec, tiny_pool, keys):
    env, params = spec.make_env()
    trainer = make_train(TINY.with_episodes(16), env, params, tiny_pool)  # one chunk: compiled with the driver's
    run = trainer.train if keys.ndim == 0 else jax.vmap(trainer.train)
    states, curve = run(keys)
    assert curve["group_reward"].shape == (*keys.shape, 1) and np.all(np.asarray(states.steps) == EPISODE)
    assert np.all(np.asarray(states.gradient_steps) > 0) and np.all(np.asarray(states.episodes) == 16)


@pytest.mark.integration
def test_make_train_is_one_jitted_run(spec, tiny_pool):
    _one_jitted_run(spec, tiny_pool, jax.random.key(0))


@pytest.mark.slow  # compiling the vmapped run takes ~40 s on 2 cores
def test_make_train_is_vmappable_over_seeds(spec, tiny_pool):
    _one_jitted_run(spec, tiny_pool, jax.random.split(jax.random.key(0), 2))


@pytest.mark.parametrize(
    "change, message",
    [
        ({"num_envs": 0}, "num_envs"),
        ({"hidden_sizes": ()}, "hidden_sizes"),
        ({"gamma": 1.0}, "gamma"),
        ({"act_epsilon": 2.0}, "act_epsilon"),
        ({"buffer_size": 10}, "buffer_size"),
        ({"epsilon_end": 0.5, "epsilon_start": 0.1}, "exploration"),
        ({"epsilon_decay_fraction": 1.5}, "epsilon_decay_fraction"),
    ],
)
def test_bad_configs_are_refused(change, message):
    with pytest.raises(WorldagentError, match=message):
        TINY.replace(**change)


def test_exploration_decays_over_its_episodes_or_a_share_of_the_budget():
    default = DQNConfig()
    assert default.decay_episodes == 1_000 and default.with_episodes(1_000).decay_episodes == 1_000
    share = default.replace(num_episodes=1_000, epsilon_decay_episodes=None)
    assert share.decay_episodes == 200 and share.with_episodes(5_000).decay_episodes == 1_000  # 0.2 of the budget
    assert DQNConfig.from_dict(share.to_dict()) == share
    steps_to_decay = 200 * 1_000 // share.num_envs
    assert float(epsilon_at(share, jnp.int32(steps_to_decay // 2), 1_000)) == pytest.approx(0.55)
    assert float(epsilon_at(share, jnp.int32(steps_to_decay), 1_000)) == pytest.approx(0.1)


def test_bad_env_algorithm_and_distribution_are_refused(spec, tiny_pool, tmp_path):
    racing_env, racing_params = registry.get("racing").make_env()
    with pytest.raises(WorldagentError, match="multi-agent"):
        make_train(TINY, racing_env, racing_params, tiny_pool)
    with pytest.raises(WorldagentError, match="harvest trains with dqn, not ppo"):
        training_config("harvest", "ppo")
    with pytest.raises(WorldagentError, match="sample"):
        training.train(spec, "dqn", TINY, object(), tmp_path)
    with pytest.raises(WorldagentError, match="DQNConfig"):
        training.train(spec, "dqn", training_config("racing"), tiny_pool, tmp_path)


@pytest.mark.integration
def test_agents_of_another_architecture_are_refused(trained, tmp_path):
    _, out = trained
    meta = json.loads((out / "policy" / "policy.json").read_text())
    meta["network"]["config"]["hidden"] = [64, 64]
    (tmp_path / "policy.json").write_text(json.dumps(meta))
    (tmp_path / "policy.msgpack").write_bytes((out / "policy" / "policy.msgpack").read_bytes())
    with pytest.raises(WorldagentError, match="another network"):
        load_policy(tmp_path)
    with pytest.raises(WorldagentError, match="no saved policy"):
        load_policy(tmp_path / "missing")


def test_load_policy_acts_with_the_recorded_exploration_rate(spec, tmp_path):
    """Saved DQN agents act epsilon-greedily as trained (greedy memoryless agents get stuck)."""
    env, params = spec.make_env()
    trainer = make_train(TINY, env, params, None)
    stacked = jax.vmap(trainer.network.init, in_axes=(0, None))(jax.random.split(jax.random.key(0), 4), jnp.zeros((9, 9, 4), jnp.uint8))
    save_policy(tmp_path, trainer.network, stacked, kind="q_network", algorithm="dqn", env="tiny_harvest",
                obs_shape=(9, 9, 4), num_actions=8, num_agents=4, extra={"act_epsilon": 0.5})  # fmt: skip
    obs = np.zeros((4, 9, 9, 4), np.uint8)
    keys = jax.random.split(jax.random.key(1), 200)
    explorer = load_policy(tmp_path).policy
    greedy = load_policy(tmp_path, greedy=True).policy
    act = jax.jit(jax.vmap(lambda policy, k: policy.act(policy.params, obs, k, None), in_axes=(None, 0)))
    acted, best = np.asarray(act(explorer, keys)), np.asarray(act(greedy, keys[:20]))
    assert (best == best[0]).all()
    differs = (acted != best[0]).mean()
    assert 0.3 < differs < 0.6  # ~0.5 · 7/8 of actions are random and not the argmax
