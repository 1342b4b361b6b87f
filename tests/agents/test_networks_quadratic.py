"""The quadratic-input actor-critic (for racing's road rays) and the crash-penalty warm-up."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from worldagent.agents.distributions import WorldPool
from worldagent.agents.networks import ActorCritic, build_network, network_config, quadratic_features
from worldagent.agents.policy import network_policy
from worldagent.agents.ppo import PPOConfig, make_train
from worldagent.envs.core import rollout
from worldagent.envs.racing.env import ParticleRacing, RacingParams, episode_metrics
from worldagent.envs.racing.spec import RACING_SETTINGS, training_params


def test_quadratic_features_are_the_inputs_and_their_pairwise_products():
    x = jnp.array([[1.0, 2.0, 3.0]])
    np.testing.assert_array_equal(quadratic_features(x), [[1, 2, 3, 1, 2, 3, 4, 6, 9]])
    assert quadratic_features(jnp.zeros((5, 7, 24))).shape == (5, 7, 24 + 24 * 25 // 2)


def test_quadratic_actor_critic_round_trips_through_its_config():
    network = ActorCritic(4, (16,), "tanh", quadratic=True)
    params = network.init(jax.random.key(0), jnp.zeros(24))
    assert params["params"]["actor"]["Dense_0"]["kernel"].shape == (24 + 300, 16)
    rebuilt = build_network("actor_critic", network_config(network))
    obs = jax.random.normal(jax.random.key(1), (3, 24))
    for a, b in zip(network.apply(params, obs), rebuilt.apply(params, obs)):
        np.testing.assert_array_equal(a, b)
    assert not build_network("actor_critic", {"num_actions": 4, "hidden": [16]}).quadratic  # agents saved before it load as before


def test_crash_penalty_warms_up_over_the_given_fraction():
    params = RacingParams()
    assert training_params(params, PPOConfig(), jnp.float32(0.0)).crash_penalty == params.crash_penalty
    warming = PPOConfig(crash_warmup=0.3)
    for fraction, expected in ((0.0, 0.0), (0.15, 150.0), (0.3, 300.0), (0.9, 300.0)):
        np.testing.assert_allclose(training_params(params, warming, jnp.float32(fraction)).crash_penalty, expected, rtol=1e-6)


@pytest.mark.slow  # ~10 s; quadratic inputs' shapes and gradients are tested in the default run
def test_ppo_with_quadratic_inputs_learns_on_road_rays(racing_pool):
    """A tiny budget on 4 tracks: the agent on the rays observation stays on the road far longer than at the start."""
    env = ParticleRacing(observation="rays", reach=64)
    config = PPOConfig(
        **RACING_SETTINGS, total_episodes=900, num_envs=16, num_steps=64, hidden=(32, 32), anneal_lr=False, learning_rate=3e-3, quadratic=True
    )  # fmt: skip
    pool = WorldPool.create(jax.tree_util.tree_map(lambda x: x[:4], racing_pool.worlds))
    trainer = make_train(config, env, env.default_params, pool, training_params)
    start = trainer.init(jax.random.key(0))
    state, _ = trainer.train_chunk(start, 40)

    def mean_return(params):
        policy = network_policy(trainer.network, params, "actor_critic")
        keys = jax.random.split(jax.random.key(7), (4, 4))
        one = lambda world, k: episode_metrics(rollout(env, policy, k, world, env.default_params, 300)[0])["return"]  # noqa: E731
        return jax.vmap(jax.vmap(one, in_axes=(None, 0)))(pool.worlds, keys).mean()

    before, after = (float(jax.jit(mean_return)(p)) for p in (start.params, state.params))
    assert before < -280  # a random policy crashes within ~15 steps (about -303)
    assert after > before + 60, (before, after)
