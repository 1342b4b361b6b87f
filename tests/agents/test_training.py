import json

import jax
import numpy as np
import pytest

from worldagent.agents.metrics import normalised_return, racing_return_bounds
from worldagent.agents.ppo import PPOConfig
from worldagent.agents.training import get_algorithm, train_racing
from worldagent.errors import WorldagentError


def test_train_racing_writes_run_and_resumes_identically(tmp_path, racing_pool, tiny_ppo):
    whole = train_racing(tiny_ppo, racing_pool, tmp_path / "whole", seed=3, progress=False, chunk_updates=2)
    assert whole.episodes >= tiny_ppo.total_episodes and whole.resumed_from_update is None
    for name in ("run.json", "checkpoint.msgpack", "curve.csv", "curve.png", "policy/policy.json", "policy/policy.msgpack"):
        assert (tmp_path / "whole" / name).is_file(), name
    assert json.loads((tmp_path / "whole" / "run.json").read_text())["seed"] == 3
    assert len(whole.curve["return"]) == int(whole.agent.extra["updates"])

    killed = train_racing(tiny_ppo, racing_pool, tmp_path / "killed", seed=3, progress=False, chunk_updates=2, stop_after_chunks=1)
    assert killed.episodes < tiny_ppo.total_episodes
    resumed = train_racing(tiny_ppo, racing_pool, tmp_path / "killed", seed=3, progress=False, chunk_updates=2)
    assert resumed.resumed_from_update == 2
    for a, b in zip(jax.tree_util.tree_leaves(whole.agent.params), jax.tree_util.tree_leaves(resumed.agent.params)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    np.testing.assert_array_equal(whole.curve["episodes"], resumed.curve["episodes"])

    with pytest.raises(WorldagentError, match="another seed"):
        train_racing(tiny_ppo, racing_pool, tmp_path / "killed", seed=4, progress=False)


def test_unknown_algorithm_and_wrong_config(tmp_path, racing_pool, tiny_ppo):
    with pytest.raises(WorldagentError, match="unknown algorithm 'sac'"):
        get_algorithm("sac")
    with pytest.raises(WorldagentError, match="unknown algorithm"):
        train_racing(tiny_ppo, racing_pool, tmp_path, algo="sac")
    with pytest.raises(WorldagentError, match="PPOConfig"):
        train_racing({"total_episodes": 10}, racing_pool, tmp_path)
    with pytest.raises(WorldagentError, match="total_episodes"):
        PPOConfig(total_episodes=0)


def test_normalised_return_bounds():
    low, high = racing_return_bounds()
    assert (low, high) == (-360.0, 100.0)
    np.testing.assert_allclose(normalised_return(np.array([-400.0, -360.0, -300.2, 100.0, 60.0])), [0, 0, 0.13, 1, 0.9130434], atol=1e-3)
    assert float(normalised_return(jax.numpy.array(-130.0))) == pytest.approx(0.5)
