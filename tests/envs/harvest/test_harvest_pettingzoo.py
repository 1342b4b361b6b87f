"""The PettingZoo ParallelEnv adapter: PettingZoo's own API and seed tests, and input checks."""

from __future__ import annotations

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from worldagent.envs.harvest.env import Harvest, make_params
from worldagent.envs.harvest.pettingzoo_env import HarvestParallelEnv
from worldagent.envs.harvest.world import DEFAULT_SIZE, HarvestMap
from worldagent.errors import WorldagentError

SHORT = make_params(can_tag=[True, False, False, False], max_steps=60)


def make_env(**kwargs):
    return HarvestParallelEnv(params=SHORT, **kwargs)


def test_parallel_api():
    parallel_api_test(make_env(), num_cycles=100)


def test_parallel_seed():
    parallel_seed_test(make_env, num_cycles=60)


def test_each_reset_samples_a_seeded_map():
    env = make_env()
    obs, infos = env.reset(seed=3)
    assert env.agents == ["agent_0", "agent_1", "agent_2", "agent_3"]
    assert obs["agent_0"].shape == (15, 15, 4) and obs["agent_0"].dtype == np.uint8
    first = infos["agent_0"]["map_seed"]
    _, infos = env.reset()
    assert infos["agent_0"]["map_seed"] != first
    _, infos = env.reset(seed=3)
    assert infos["agent_0"]["map_seed"] == first


def test_episode_ends_for_everyone_and_reports_metrics():
    env = make_env(world=HarvestMap.from_str("\n".join(["A" * 8 if 0 < r < 7 else "." * 8 for r in range(8)]).replace("A", ".", 1)))
    env.reset(seed=0)
    for _ in range(60):
        _, rewards, _, truncations, _ = env.step({agent: 1 for agent in env.agents})
    assert all(truncations.values()) and env.agents == []
    metrics = env.episode_metrics()
    assert metrics["group_reward"] == sum(metrics["returns"]) > 0
    with pytest.raises(WorldagentError, match="reset"):
        env.step({})


def test_bad_input_is_a_one_line_error():
    env = make_env()
    env.reset(seed=0)
    with pytest.raises(WorldagentError, match="missing"):
        env.step({"agent_0": 0})
    with pytest.raises(WorldagentError, match=r"\[0, 8\)"):
        env.step({agent: 9 for agent in env.agents})
    with pytest.raises(WorldagentError, match="spawn corner"):
        make_env(world=HarvestMap.from_str("#....\n.....\n....."))
    with pytest.raises(WorldagentError, match="exactly 4 agents"):
        HarvestParallelEnv(env=Harvest(num_agents=2))
    with pytest.raises(WorldagentError, match="render_mode"):
        make_env(render_mode="human")


def test_rgb_render():
    env = make_env(render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (DEFAULT_SIZE * 16, DEFAULT_SIZE * 16, 3) and frame.dtype == np.uint8
