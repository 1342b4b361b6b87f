import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from worldagent.agents.networks import ActorCritic, QNetwork
from worldagent.agents.policy import (
    CallablePolicy,
    host_episode,
    load_policy,
    racing_driver_policy,
    save_policy,
    scripted_policy,
)
from worldagent.envs.core import rollout
from worldagent.envs.racing.env import episode_metrics
from worldagent.errors import WorldagentError


def _saved(tmp_path, hidden=(16,)):
    net = ActorCritic(4, hidden)
    params = net.init(jax.random.key(0), jnp.zeros(260))
    save_policy(
        tmp_path, net, params, kind="actor_critic", algorithm="ppo", env="racing", obs_shape=(260,), num_actions=4, training={"total_episodes": 1}
    )
    return net, params


def test_save_load_acts_identically(tmp_path):
    net, params = _saved(tmp_path)
    obs = jax.random.uniform(jax.random.key(1), (32, 260))
    keys = jax.random.split(jax.random.key(2), 32)
    for greedy in (False, True):
        agent = load_policy(tmp_path, env="racing", greedy=greedy)
        assert agent.algorithm == "ppo" and agent.num_actions == 4 and agent.training == {"total_episodes": 1}
        logits, _ = net.apply(params, obs)
        got = jax.vmap(agent.policy)(obs, keys)
        want = jnp.argmax(logits, -1) if greedy else jax.vmap(jax.random.categorical)(keys, logits)
        np.testing.assert_array_equal(got, want)


def test_load_refusals(tmp_path):
    _saved(tmp_path)
    with pytest.raises(WorldagentError, match="racing agent, not a harvest"):
        load_policy(tmp_path, env="harvest")
    with pytest.raises(WorldagentError, match="not a acktr"):
        load_policy(tmp_path, algorithm="acktr")
    config = json.loads((tmp_path / "policy.json").read_text())
    config["network"]["config"]["hidden"] = [32]  # another architecture than the weights
    (tmp_path / "policy.json").write_text(json.dumps(config))
    with pytest.raises(WorldagentError, match="another network"):
        load_policy(tmp_path)
    config["network"]["kind"] = "transformer"
    (tmp_path / "policy.json").write_text(json.dumps(config))
    with pytest.raises(WorldagentError, match="unknown network architecture"):
        load_policy(tmp_path)
    config["format_version"] = 99
    (tmp_path / "policy.json").write_text(json.dumps(config))
    with pytest.raises(WorldagentError, match="format version 99"):
        load_policy(tmp_path)
    with pytest.raises(WorldagentError, match="no saved policy"):
        load_policy(tmp_path / "nothing")


def test_stacked_q_networks_round_trip(tmp_path):
    net = QNetwork(8, (16,), obs_rank=3)
    params = jax.vmap(lambda k: net.init(k, jnp.zeros((5, 5, 4))))(jax.random.split(jax.random.key(0), 4))
    save_policy(tmp_path, net, params, kind="q_network", algorithm="dqn", env="harvest", obs_shape=(5, 5, 4), num_actions=8, num_agents=4)
    agent = load_policy(tmp_path, env="harvest")
    obs = jax.random.uniform(jax.random.key(1), (4, 5, 5, 4))
    want = jnp.stack([jnp.argmax(net.apply(jax.tree_util.tree_map(lambda x: x[i], params), obs[i])) for i in range(4)])
    np.testing.assert_array_equal(agent.policy(obs, jax.random.key(2)), want)


def test_scripted_policies_fit(racing_env, racing_pool):
    driver = racing_driver_policy()
    world = racing_pool.sample(jax.random.key(0))
    final, _ = jax.jit(lambda k: rollout(racing_env, driver.as_rollout_policy(), k, world, racing_env.default_params, 300))(jax.random.key(0))
    assert bool(episode_metrics(final)["lap_completed"])
    from worldagent.envs.harvest.env import Harvest

    harvest = Harvest()
    obs = jnp.zeros((4, *harvest.observation_shape), jnp.uint8)
    for name in ("random", "greedy"):
        assert scripted_policy("harvest", name)(obs, jax.random.key(0)).shape == (4,)
    with pytest.raises(WorldagentError, match="no scripted policy"):
        scripted_policy("racing", "random")


def test_callable_policy_host_loop(racing_env, racing_pool):
    calls = []

    def north(obs):
        calls.append(obs.shape)
        return 2  # accelerate north: leaves the road within a few dozen steps

    state = host_episode(racing_env, CallablePolicy(north), jax.random.key(0), racing_pool.sample(jax.random.key(0)), racing_env.default_params)
    assert calls[0] == racing_env.observation_shape and bool(state.done)
    with pytest.raises(WorldagentError, match="callable"):
        CallablePolicy(3)
