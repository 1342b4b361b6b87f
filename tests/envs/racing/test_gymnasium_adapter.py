"""The Gymnasium adapter: registration, check_env, seeding, and clear errors."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import worldagent  # noqa: F401  (registers worldagent/ParticleRacing-v0)
from worldagent.envs.adapters import ParticleRacingGym
from worldagent.errors import WorldagentError


@pytest.fixture(scope="module")
def gym_env(tmp_path_factory):
    # A small track pool, cached in a temporary folder rather than the user's home.
    return gymnasium.make("worldagent/ParticleRacing-v0", render_mode="rgb_array", pool_size=16, cache_dir=tmp_path_factory.mktemp("cache")).unwrapped


def test_check_env_passes(gym_env):
    check_env(gym_env, skip_render_check=False)


def test_reset_seed_picks_the_track_and_is_reproducible(gym_env):
    obs_a, info_a = gym_env.reset(seed=7)
    obs_b, info_b = gym_env.reset(seed=7)
    obs_c, info_c = gym_env.reset(seed=8)
    assert info_a["track_seed"] == info_b["track_seed"] != info_c["track_seed"]
    np.testing.assert_array_equal(obs_a, obs_b)
    assert gym_env.observation_space.contains(obs_a)


def test_an_episode_ends_with_a_crash_or_a_lap_or_the_step_limit(gym_env):
    gym_env.reset(seed=0)
    rewards, done, steps = [], False, 0
    while not done:
        _, reward, terminated, truncated, info = gym_env.step(gym_env.action_space.sample())
        rewards.append(reward)
        done, steps = terminated or truncated, steps + 1
    assert steps <= 300
    assert info["crashed"] or info["lap_completed"] or steps == 300
    frame = gym_env.render()
    assert frame.shape == (256, 256, 3) and frame.dtype == np.uint8


def test_reset_on_a_given_world(gym_env, track):
    gym_env.reset(seed=0, options={"world": track})
    np.testing.assert_array_equal(np.asarray(gym_env.world.centreline), track.centreline)


def test_bad_actions_and_render_modes_are_refused(gym_env):
    gym_env.reset(seed=0)
    for action in (4, -1):
        with pytest.raises(WorldagentError, match="valid action"):
            gym_env.step(action)
    with pytest.raises(ValueError, match="render_mode"):
        ParticleRacingGym(render_mode="human")
