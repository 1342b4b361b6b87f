"""The host driver (``training.train``) and the algorithm table (``algorithms``)."""

import json

import jax
import numpy as np
import pytest

from worldagent.agents import training
from worldagent.agents.acktr import ACKTRConfig
from worldagent.agents.algorithms import ALGORITHMS, get_algorithm, training_config
from worldagent.agents.dqn import DQNConfig
from worldagent.agents.ppo import PPOConfig
from worldagent.agents.training import CHECKPOINT_FILE, plotted_metrics, train
from worldagent.envs import registry
from worldagent.envs.racing.metrics import normalised_return, racing_return_bounds
from worldagent.errors import WorldagentError


@pytest.mark.integration
def test_train_writes_run_and_resumes_identically(tmp_path, monkeypatch, racing_spec, racing_pool, tiny_ppo):
    run = lambda out, **kw: train(racing_spec, "ppo", tiny_ppo, racing_pool, tmp_path / out, seed=3, progress=False, chunk_updates=2, **kw)  # noqa: E731
    whole = run("whole")
    assert whole.episodes >= tiny_ppo.total_episodes and whole.resumed_from_update is None
    for name in ("run.json", "checkpoint.msgpack", "curve.csv", "curve.png", "policy/policy.json", "policy/policy.msgpack"):
        assert (tmp_path / "whole" / name).is_file(), name
    record = json.loads((tmp_path / "whole" / "run.json").read_text())
    assert (record["seed"], record["env"], record["algorithm"], record["options"]) == (3, "racing", "ppo", racing_spec.check_options({}))
    assert len(whole.curve["return"]) == int(whole.agent.extra["updates"])
    for field in ("crashed", "lap_completed", "progress", "policy_loss", "active"):  # the env's info entries are curve columns
        assert field in whole.curve, field

    killed = run("killed", stop_after_chunks=1)
    assert killed.episodes < tiny_ppo.total_episodes
    resumed = run("killed")
    assert resumed.resumed_from_update == 2
    for a, b in zip(jax.tree_util.tree_leaves(whole.agent.params), jax.tree_util.tree_leaves(resumed.agent.params)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    np.testing.assert_array_equal(whole.curve["episodes"], resumed.curve["episodes"])

    # Checkpoints are timed, not per chunk; one is written when an exception (Ctrl-C) stops the loop.
    monkeypatch.setattr(training, "CHECKPOINT_SECONDS", float("inf"))
    written, chunks = [], []
    write_bytes = training.write_bytes
    monkeypatch.setattr(training, "write_bytes", lambda path, blob: (written.append(path.name), write_bytes(path, blob))[1])

    def interrupt_after_two_chunks(run):
        chunks.append(run)
        if len(chunks) == 2:
            raise KeyboardInterrupt
        return {}

    monkeypatch.setattr(training, "status", interrupt_after_two_chunks)
    one_update = lambda: train(racing_spec, "ppo", tiny_ppo, racing_pool, tmp_path / "interrupted", seed=3, progress=False, chunk_updates=1)  # noqa: E731
    with pytest.raises(KeyboardInterrupt):
        one_update()
    assert written.count(CHECKPOINT_FILE) == 1
    monkeypatch.undo()
    resumed = one_update()
    assert resumed.resumed_from_update == 2
    for a, b in zip(jax.tree_util.tree_leaves(whole.agent.params), jax.tree_util.tree_leaves(resumed.agent.params)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))

    with pytest.raises(WorldagentError, match="another seed"):
        train(racing_spec, "ppo", tiny_ppo, racing_pool, tmp_path / "killed", seed=4, progress=False)
    with pytest.raises(WorldagentError, match="another algorithm"):
        train(racing_spec, "acktr", ACKTRConfig(total_episodes=8), racing_pool, tmp_path / "killed", seed=3, progress=False)


def test_unknown_algorithm_wrong_config_and_bad_options(tmp_path, racing_pool, tiny_ppo):
    with pytest.raises(WorldagentError, match="unknown algorithm 'sac'"):
        get_algorithm("sac")
    with pytest.raises(WorldagentError, match="unknown algorithm"):
        train("racing", "sac", tiny_ppo, racing_pool, tmp_path)
    with pytest.raises(WorldagentError, match="PPOConfig"):
        train("racing", "ppo", {"total_episodes": 10}, racing_pool, tmp_path)
    with pytest.raises(WorldagentError, match="no option 'tagger'"):
        train("racing", "ppo", tiny_ppo, racing_pool, tmp_path, options={"tagger": 0})
    with pytest.raises(WorldagentError, match="chunk_updates"):
        train("racing", "ppo", tiny_ppo, racing_pool, tmp_path, chunk_updates=0)


def test_training_config_follows_the_spec():
    assert set(ALGORITHMS) == {"ppo", "acktr", "dqn"}
    assert isinstance(training_config("racing"), PPOConfig) and isinstance(training_config("harvest"), DQNConfig)
    assert training_config("racing", episodes=12).total_episodes == 12
    assert training_config("harvest", episodes=12).num_episodes == 12
    config = training_config("racing", "acktr", episodes=20, num_envs=4)
    assert isinstance(config, ACKTRConfig) and (config.total_episodes, config.num_envs) == (20, 4)
    assert training_config("racing", base=PPOConfig(num_envs=2), episodes=5) == PPOConfig(num_envs=2, total_episodes=5)
    with pytest.raises(WorldagentError, match="racing trains with ppo, acktr, not dqn"):
        training_config("racing", "dqn")
    with pytest.raises(WorldagentError, match="no field 'lr'"):
        training_config("racing", lr=0.1)
    with pytest.raises(WorldagentError, match="takes a PPOConfig"):
        training_config("racing", base=DQNConfig())


def test_plotted_metrics_are_the_main_and_highlighted_ones():
    assert plotted_metrics(registry.get("racing"), ["return", "crashed", "loss"]) == ["return", "crashed"]
    assert plotted_metrics(registry.get("harvest"), ["group_reward", "conflict", "equality"]) == ["group_reward", "conflict", "equality"]


def test_normalised_return_bounds():
    low, high = racing_return_bounds()
    assert (low, high) == (-360.0, 100.0)
    np.testing.assert_allclose(normalised_return(np.array([-400.0, -360.0, -300.2, 100.0, 60.0])), [0, 0, 0.13, 1, 0.9130434], atol=1e-3)
    assert float(normalised_return(jax.numpy.array(-130.0))) == pytest.approx(0.5)


@pytest.mark.integration
def test_keep_every_keeps_loadable_agents_along_the_way(tmp_path, racing_spec, racing_pool, tiny_ppo):
    from worldagent.agents.loaders import load_agent

    with pytest.raises(WorldagentError, match="keep_every=0; pass a positive number"):
        train(racing_spec, "ppo", tiny_ppo, racing_pool, tmp_path / "bad", keep_every=0, progress=False)
    assert not (tmp_path / "bad").exists()  # refused before anything is written
    result = train(racing_spec, "ppo", tiny_ppo, racing_pool, tmp_path / "kept", seed=3, progress=False, chunk_updates=1, keep_every=16)
    kept = sorted((tmp_path / "kept" / training.SNAPSHOTS_DIR).iterdir(), key=lambda p: int(p.name))
    counts = [int(p.name) for p in kept]
    assert len(kept) >= 3 and counts[-1] == result.episodes  # the last chunk passed a multiple of 16 too
    assert len({c // 16 for c in counts}) == len(counts)  # one per multiple of 16 passed
    leaves = lambda params: [np.asarray(x) for x in jax.tree_util.tree_leaves(params)]  # noqa: E731
    for folder, count in zip(kept, counts):
        agent = load_agent(racing_spec, folder)  # what --agent takes: diff, evaluate, explore
        assert agent is not None and training.load_policy(folder, env="racing").extra["episodes"] == count
    first, last = (leaves(training.load_policy(kept[i], env="racing").params) for i in (0, -1))
    assert any(not np.array_equal(a, b) for a, b in zip(first, last))  # an earlier agent, not the final one again
    for a, b in zip(last, leaves(result.agent.params)):
        np.testing.assert_array_equal(a, b)
