import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from worldagent.agents.loaders import agent_options, load_agent
from worldagent.agents.networks import ActorCritic, QNetwork
from worldagent.agents.saved import load_policy, save_policy
from worldagent.envs.core import rollout
from worldagent.envs.racing.env import episode_metrics
from worldagent.errors import WorldagentError


def _saved(tmp_path, hidden=(16,), obs_shape=(260,), extra=None):
    net = ActorCritic(4, hidden)
    params = net.init(jax.random.key(0), jnp.zeros(obs_shape))
    save_policy(
        tmp_path,
        net,
        params,
        kind="actor_critic",
        algorithm="ppo",
        env="racing",
        obs_shape=obs_shape,
        num_actions=4,
        training={"total_episodes": 1},
        extra=extra,
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
        got = jax.vmap(lambda o, k: agent.policy.act(agent.params, o, k, None))(obs, keys)
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
    np.testing.assert_array_equal(agent.policy.act(agent.params, obs, jax.random.key(2), None), want)


def test_load_agent_takes_run_dirs_policy_dirs_and_scripted_names(tmp_path, racing_spec, racing_env, racing_pool):
    _saved(tmp_path / "run" / "policy", obs_shape=racing_env.observation_shape)
    obs = jnp.zeros(racing_env.observation_shape)
    for text in (tmp_path / "run", tmp_path / "run" / "policy"):
        policy = load_agent(racing_spec, str(text), greedy=True)
        assert policy.act(policy.params, obs, jax.random.key(0), None).shape == ()
    driver = load_agent(racing_spec, "driver")
    assert driver.privileged and driver.name == "driver"
    world = racing_pool.sample(jax.random.key(0))
    final, _ = jax.jit(lambda k: rollout(racing_env, driver, k, world, racing_env.default_params, 300))(jax.random.key(0))
    assert bool(episode_metrics(final)["lap_completed"])
    harvest_obs = jnp.zeros((4, 15, 15, 4), jnp.uint8)
    for name in ("random", "greedy"):
        policy = load_agent("harvest", name, options={"tagger": (0,)})
        assert policy.act(policy.params, harvest_obs, jax.random.key(0), None).shape == (4,)
    with pytest.raises(WorldagentError, match="a scripted policy \\(driver, random\\)"):
        load_agent(racing_spec, "greedy")
    with pytest.raises(WorldagentError, match="racing agent, not a harvest"):
        load_agent("harvest", str(tmp_path / "run"))


def test_saved_agents_play_with_the_options_they_trained_with(tmp_path, racing_spec):
    rays = racing_spec.make_env({"observation": "rays"})[0].observation_shape
    _saved(tmp_path / "run" / "policy", obs_shape=rays, extra={"options": {"observation": "rays", "respawn_speed": 0.5, "gone": 1}})
    run = str(tmp_path / "run")
    options = agent_options(racing_spec, run)  # recorded options fill what is not given; unknown ones are dropped
    assert options["observation"] == "rays" and options["respawn_speed"] == 0.5 and "gone" not in options
    assert agent_options(racing_spec, run, {"respawn_speed": 0.0})["respawn_speed"] == 0.0
    assert agent_options(racing_spec, "driver") == racing_spec.check_options()
    assert load_agent(racing_spec, run, options=options).act is not None
    with pytest.raises(WorldagentError, match=r"trained on observations of shape \(26,\).*--option"):
        load_agent(racing_spec, run, options={"observation": "route"})
