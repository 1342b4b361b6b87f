import jax
import jax.numpy as jnp
import numpy as np

from worldagent.agents.networks import ActorCritic
from worldagent.agents.rollouts import collect, episode_summary, gae, init_runner, nstep_returns


def _gae_reference(rewards, values, dones, last_value, gamma, lam):
    advantages = np.zeros_like(rewards)
    next_adv, next_value = np.zeros_like(last_value), last_value
    for t in reversed(range(len(rewards))):
        not_done = 1.0 - dones[t]
        delta = rewards[t] + gamma * next_value * not_done - values[t]
        next_adv = delta + gamma * lam * not_done * next_adv
        advantages[t], next_value = next_adv, values[t]
    return advantages


def test_gae_and_nstep_match_reference():
    rng = np.random.default_rng(0)
    rewards, values = rng.normal(size=(7, 3)).astype(np.float32), rng.normal(size=(7, 3)).astype(np.float32)
    dones = rng.random((7, 3)) < 0.3
    last = rng.normal(size=3).astype(np.float32)
    adv, targets = gae(rewards, values, dones, last, 0.9, 0.8)
    np.testing.assert_allclose(adv, _gae_reference(rewards, values, dones, last, 0.9, 0.8), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(targets, np.asarray(adv) + values, rtol=1e-6)
    # lambda = 1 GAE targets are the n-step returns
    _, full = gae(rewards, values, dones, last, 0.9, 1.0)
    np.testing.assert_allclose(nstep_returns(rewards, dones, last, 0.9), full, rtol=1e-5, atol=1e-5)


def test_collect_shapes_worlds_and_episodes(racing_env, racing_pool):
    params = racing_env.default_params
    net = ActorCritic(racing_env.num_actions, (16,))
    net_params = net.init(jax.random.key(0), jnp.zeros(racing_env.observation_shape))
    runner = init_runner(jax.random.key(1), racing_env, params, racing_pool, 16)
    starts = np.asarray(runner.state.world.centreline[:, 0])
    assert len(np.unique(starts.round(5), axis=0)) > 1  # envs start on different worlds
    step = jax.jit(lambda k, r: collect(k, r, net.apply, net_params, racing_env, params, racing_pool, 40))
    runner, traj, last_value = step(jax.random.key(2), runner)
    assert traj.obs.shape == (40, 16, *racing_env.observation_shape) and traj.action.shape == (40, 16) and last_value.shape == (16,)
    summary = episode_summary(traj)
    assert int(summary["episodes"]) == int(traj.done.sum()) > 0  # a random policy crashes quickly
    ended = np.asarray(traj.done)
    np.testing.assert_allclose(np.asarray(traj.episode["return"])[ended].mean(), float(summary["return"]), rtol=1e-5)
    assert float(summary["crashed"]) > 0.5
    # per-episode returns are the sums of that episode's rewards
    rewards = np.asarray(traj.reward)[:, 0]
    first_end = int(np.argmax(ended[:, 0]))
    np.testing.assert_allclose(np.asarray(traj.episode["return"])[first_end, 0], rewards[: first_end + 1].sum(), rtol=1e-5)
