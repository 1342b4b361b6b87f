"""Stable-Baselines3 on ``gymnasium.make_vec`` through ``vector.to_sb3`` (issue 30, item 8).

The info translation is pure and tested in the default run; the adapter and the training test
need the ``sb3`` extra (torch) and are skipped without it; training is also marked slow.
"""

from __future__ import annotations

import sys

import gymnasium
import numpy as np
import pytest

import worldagent  # noqa: F401  (registers worldagent/ParticleRacing-v0)
from worldagent.envs.racing.env import RacingParams
from worldagent.envs.vector import sb3_infos, split_info, to_sb3
from worldagent.errors import WorldagentError

NUM_ENVS = 4
POOL_SIZE = 4


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("cache")


def make_envs(cache, num_envs=NUM_ENVS, **kwargs):
    return gymnasium.make_vec("worldagent/ParticleRacing-v0", num_envs=num_envs, pool_size=POOL_SIZE, cache_dir=cache, **kwargs)


def test_batched_info_splits_per_env_keeping_only_masked_entries():
    info = {"progress": np.array([0.1, 0.2, 0.3]), "final_info": {"steps": np.array([0, 5, 7]), "_steps": np.array([False, True, True])}}
    info["_final_info"] = np.array([False, True, True])
    infos = split_info(info, 3)
    assert [sorted(one) for one in infos] == [["progress"], ["final_info", "progress"], ["final_info", "progress"]]
    assert infos[1]["final_info"] == {"steps": 5} and infos[2]["progress"] == 0.3


def test_ended_episodes_carry_their_last_observation_and_whether_time_ran_out():
    final_obs = np.arange(6.0).reshape(3, 2)
    info = {"final_obs": final_obs, "_final_obs": np.array([True, True, False]), "crashed": np.array([True, False, False])}
    terminated, truncated = np.array([True, False, False]), np.array([False, True, False])
    infos = sb3_infos(info, terminated, truncated)
    np.testing.assert_array_equal(infos[0]["terminal_observation"], [0.0, 1.0])
    np.testing.assert_array_equal(infos[1]["terminal_observation"], [2.0, 3.0])
    assert infos[0]["TimeLimit.truncated"] is False and infos[1]["TimeLimit.truncated"] is True
    assert "terminal_observation" not in infos[2] and "final_obs" not in infos[0]
    assert [one["crashed"] for one in infos] == [True, False, False]


def test_the_vector_envs_episode_ends_translate_to_sb3s(cache):
    envs = make_envs(cache, params=RacingParams(max_steps=3))
    envs.reset(seed=0)
    for _ in range(3):
        obs, _, terminated, truncated, info = envs.step(np.zeros(NUM_ENVS, np.int64))
    infos = sb3_infos(info, terminated, truncated)
    assert (terminated | truncated).all()
    for index, one in enumerate(infos):
        np.testing.assert_array_equal(one["terminal_observation"], info["final_obs"][index])
        assert not np.array_equal(one["terminal_observation"], obs[index])  # obs is already the next episode's
        assert one["TimeLimit.truncated"] == bool(truncated[index] and not terminated[index])


def test_without_sb3_the_adapter_names_the_extra(cache, monkeypatch):
    monkeypatch.setitem(sys.modules, "stable_baselines3", None)  # as if not installed
    monkeypatch.delitem(sys.modules, "worldagent.envs.sb3", raising=False)
    with pytest.raises(WorldagentError, match=r"to_sb3 needs Stable-Baselines3 \(stable_baselines3 is missing\): pip install 'worldagent\[sb3\]'"):
        to_sb3(make_envs(cache))


def test_sb3_accepts_the_adapted_vector_env(cache):
    pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.vec_env import VecEnv

    envs = to_sb3(make_envs(cache, params=RacingParams(max_steps=3)))
    assert isinstance(envs, VecEnv) and envs.num_envs == NUM_ENVS
    assert envs.observation_space.shape == envs.unwrapped.venv.single_observation_space.shape
    envs.seed(7)
    first = envs.reset()
    envs.seed(7)
    np.testing.assert_array_equal(envs.reset(), first)  # SB3's seed seeds the batch
    for _ in range(3):
        obs, rewards, dones, infos = envs.step(np.zeros(NUM_ENVS, np.int64))
    assert obs.shape == first.shape and rewards.dtype == np.float32 and dones.all()
    assert all("terminal_observation" in one and "episode" in one for one in infos)  # VecMonitor's episode statistics
    assert envs.get_attr("num_envs") == [NUM_ENVS] * NUM_ENVS
    with pytest.raises(WorldagentError, match="one jitted batch"):
        envs.env_method("render")


def test_sb3_refuses_next_step_autoreset_envs_with_the_fix():
    pytest.importorskip("stable_baselines3")
    envs = gymnasium.make_vec("CartPole-v1", num_envs=2, vectorization_mode="sync")
    with pytest.raises(WorldagentError, match="make_vec_env"):
        to_sb3(envs)


@pytest.mark.slow
def test_sb3_ppo_learns_to_crash_less_on_the_vector_env_with_respawn(cache):
    """SB3's PPO (its defaults but shorter rollouts), 40,960 steps (about 25 s on 2 cores): its reward per step rises as it stops crashing."""
    pytest.importorskip("stable_baselines3")
    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(1)
    respawn = RacingParams(respawn=True)  # training-time respawn: every episode runs to the lap or the time limit
    model = PPO("MlpPolicy", to_sb3(make_envs(cache, 16, params=respawn)), n_steps=128, batch_size=256, seed=0, device="cpu")

    def reward_per_step() -> float:
        envs = to_sb3(make_envs(cache, 16, params=respawn))
        envs.seed(1)
        obs, total = envs.reset(), 0.0
        for _ in range(300):
            obs, reward, _, _ = envs.step(model.predict(obs, deterministic=True)[0])
            total += float(reward.mean())
        return total / 300

    before = reward_per_step()
    model.learn(40_960)
    assert model.num_timesteps == 40_960 and len(model.ep_info_buffer) > 0
    after = reward_per_step()
    assert after > before / 2, (before, after)  # before: about -84 a step (a crash every 3-4 steps)
