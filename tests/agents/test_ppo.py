import dataclasses

import jax
import numpy as np
import pytest

from worldagent.agents.distributions import WorldPool
from worldagent.agents.policy import network_policy
from worldagent.agents.ppo import PPOConfig, make_train, max_updates
from worldagent.envs.core import rollout
from worldagent.envs.racing.env import episode_metrics
from worldagent.envs.racing.spec import RACING_SETTINGS, training_params
from worldagent.errors import WorldagentError

# The learning test's budget: a few dozen updates, a few seconds of training (with racing's settings: its spec's).
LEARN = PPOConfig(
    **RACING_SETTINGS, total_episodes=900, num_envs=16, num_steps=64, num_minibatches=4, update_epochs=4, hidden=(32, 32), anneal_lr=False,
    learning_rate=3e-3,
)  # fmt: skip


def _mean_returns(env, network, stacked_params, worlds, key):
    """f[P] mean return of each of P stacked parameter sets over the same worlds x 4 episodes."""

    def one(params, world, k):
        policy = network_policy(network, params, "actor_critic")
        final, _ = rollout(env, policy, k, world, env.default_params, 300)
        return episode_metrics(final)["return"]

    n = worlds.centreline.shape[0]
    keys = jax.random.split(key, (n, 4))
    per_params = lambda p: jax.vmap(jax.vmap(one, in_axes=(None, None, 0)), in_axes=(None, 0, 0))(p, worlds, keys).mean()  # noqa: E731
    return np.asarray(jax.jit(jax.vmap(per_params))(stacked_params))


@pytest.mark.integration
def test_ppo_raises_return_on_fixed_tracks_for_two_seeds(racing_env, racing_pool):
    pool = WorldPool.create(jax.tree_util.tree_map(lambda x: x[:4], racing_pool.worlds))
    trainer = make_train(LEARN, racing_env, racing_env.default_params, pool, training_params)
    starts = jax.vmap(trainer.init)(jax.random.split(jax.random.key(0), 2))
    states, curves = jax.vmap(lambda s: trainer.train_chunk(s, 60))(starts)  # two seeds at once
    both = jax.tree_util.tree_map(lambda a, b: np.concatenate([a, b]), starts.params, states.params)
    before0, before1, after0, after1 = _mean_returns(racing_env, trainer.network, both, pool.worlds, jax.random.key(7))
    # a random policy crashes within ~15 steps (about -303); a learning one stays on the road far longer
    assert before0 < -280 and before1 < -280
    assert after0 > before0 + 60 and after1 > before1 + 60, (before0, before1, after0, after1)
    assert np.all(np.asarray(curves["active"]) == 1)


@pytest.mark.integration
def test_an_env_step_budget_stops_training_at_exactly_its_updates_and_anneals_by_it(racing_env, racing_pool, tiny_ppo):
    steps = 3 * tiny_ppo.num_envs * tiny_ppo.num_steps - 1  # spent during the 3rd update
    config = dataclasses.replace(tiny_ppo, total_episodes=10**6, total_env_steps=steps)
    trainer = make_train(config, racing_env, racing_env.default_params, racing_pool)
    assert trainer.max_updates == 3
    state, curve = trainer.train_chunk(trainer.init(jax.random.key(0)), 5)
    assert int(state.update) == 3 and int(state.env_steps) == 3 * tiny_ppo.num_envs * tiny_ppo.num_steps and trainer.done(state)
    np.testing.assert_array_equal(np.asarray(curve["active"]), [1, 1, 1, 0, 0])
    rates = np.asarray(curve["learning_rate"])[:3]
    assert rates[0] > rates[1] > rates[2] and rates[2] < 0.5 * tiny_ppo.learning_rate  # annealed by steps, not by 10**6 episodes
    by_episodes = make_train(dataclasses.replace(tiny_ppo, total_episodes=10**6), racing_env, racing_env.default_params, racing_pool)
    assert not by_episodes.done(state)  # without the step budget the same state trains on
    with pytest.raises(WorldagentError, match="total_env_steps=-1"):
        dataclasses.replace(tiny_ppo, total_env_steps=-1)


@pytest.mark.integration
def test_train_is_vmappable_and_stops_at_the_budget(racing_env, racing_pool, tiny_ppo):
    trainer = make_train(tiny_ppo, racing_env, racing_env.default_params, racing_pool)
    states, curves = jax.vmap(trainer.train)(jax.random.split(jax.random.key(0), 2))
    episodes = np.asarray(states.episodes)
    assert np.all(episodes >= tiny_ppo.total_episodes)
    active = np.asarray(curves["active"]) > 0
    assert np.all(np.isnan(np.asarray(curves["return"])[~active]))  # updates after the budget are skipped
    np.testing.assert_array_equal(np.asarray(curves["episodes"])[:, -1][active[:, -1]], episodes[active[:, -1]])
    assert not np.array_equal(
        np.asarray(states.params["params"]["actor"]["Dense_0"]["kernel"][0]), np.asarray(states.params["params"]["actor"]["Dense_0"]["kernel"][1])
    )


@pytest.mark.parametrize(
    "field, value",
    [
        ("total_episodes", 0),
        ("num_envs", -1),
        ("num_minibatches", 3),
        ("learning_rate", 0.0),
        ("gamma", 1.5),
        ("activation", "gelu"),
        ("hidden", ()),
    ],
)
def test_bad_configs_refused(field, value):
    with pytest.raises(WorldagentError, match=field):
        PPOConfig(**{field: value})


def test_config_round_trip():
    config = PPOConfig(hidden=[32, 16])
    assert config.hidden == (32, 16)
    assert PPOConfig.from_dict(config.to_dict()) == config
    with pytest.raises(WorldagentError, match="unknown fields"):
        PPOConfig.from_dict({**config.to_dict(), "tau": 1})


def test_budget_bound():
    assert max_updates(10_000, 64, 128, 300) * 64 * 128 // 300 >= 10_000
    assert dataclasses.asdict(PPOConfig())["total_episodes"] == 10_000
