"""The batched evaluator: the same episodes as one-by-one rollouts, on many worlds at once."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from worldagent.agents.external import HostPolicy
from worldagent.agents.loaders import scripted_policy
from worldagent.agents.policy import Policy
from worldagent.envs.core import rollout
from worldagent.envs.harvest import Harvest, generate_maps, make_params
from worldagent.envs.racing.env import ParticleRacing
from worldagent.envs.racing.tracks import generate_tracks
from worldagent.errors import WorldagentError
from worldagent.evaluation.local import episode_keys, episodes_per_call, evaluate, summarise

RACING = ParticleRacing()


@pytest.fixture(scope="module")
def worlds():
    return generate_tracks(np.arange(6))


def random_racing_policy():
    return Policy(None, lambda params, obs, key, state=None: jax.random.randint(key, (), 0, 4), "random")


def test_metrics_have_a_row_per_world_and_a_column_per_episode(worlds):
    metrics = evaluate(RACING, random_racing_policy(), worlds, 5, jax.random.key(0))
    assert set(metrics) == {"return", "crashed", "lap_completed", "progress", "steps"}
    assert all(value.shape == (6, 5) for value in metrics.values())
    assert len(np.unique(metrics["return"])) > 6  # different worlds and different episodes differ
    again = evaluate(RACING, random_racing_policy(), worlds, 5, jax.random.key(0))
    np.testing.assert_array_equal(again["return"], metrics["return"])


def test_each_episode_is_the_episode_a_plain_rollout_plays(worlds):
    """Same key, same world: the batched while-loop and a one-episode scan agree."""
    policy = random_racing_policy()
    metrics = evaluate(RACING, policy, worlds, 3, jax.random.key(1))
    keys = episode_keys(jax.random.key(1), 6, 3)
    from worldagent.evaluation.local import run_episode

    for b, r in [(0, 0), (2, 1), (5, 2)]:
        world = jax.tree_util.tree_map(lambda leaf: leaf[b], worlds)
        single = jax.jit(lambda k, w: run_episode(RACING, policy, k, w, RACING.default_params, 300))(keys[b, r], world)
        assert float(single["return"]) == pytest.approx(float(metrics["return"][b, r]), abs=1e-4)
    # ... and the driver's episodes are those of core.rollout (a deterministic policy)
    driver = scripted_policy("racing", "driver")
    metrics = evaluate(RACING, driver, worlds, 2, jax.random.key(2))
    world = jax.tree_util.tree_map(lambda leaf: leaf[4], worlds)
    final, _ = rollout(RACING, driver, jax.random.key(9), world, RACING.default_params, 300)
    assert float(final.episode_return) == pytest.approx(float(metrics["return"][4, 0]), abs=1e-3)
    assert int(final.time) == int(metrics["steps"][4, 1])


def test_an_external_agent_goes_to_the_host_evaluator_with_the_same_output(worlds):
    always_north = Policy(None, lambda params, obs, key, state=None: jnp.int32(2), "north")
    jitted = evaluate(RACING, always_north, worlds, 2, jax.random.key(0))
    calls = []
    host = evaluate(RACING, HostPolicy(lambda obs: calls.append(obs.shape) or np.full(len(obs), 2), RACING.num_actions), worlds, 2, jax.random.key(0))
    # one call per step for all 6 worlds x 2 repeats, padded to the evaluator's one batch size
    assert calls[0] == (episodes_per_call(RACING), *RACING.observation_shape)
    assert set(host) == set(jitted)
    for name in jitted:
        np.testing.assert_array_equal(host[name], jitted[name])


def test_an_env_sets_its_own_call_size_on_a_cpu_and_the_variable_still_wins(monkeypatch):
    """Harvest's episodes all run max_steps, so its calls hold 64 episodes; racing keeps the evaluator's 256."""
    monkeypatch.delenv("WORLDAGENT_EPISODES_PER_CALL")  # the tests' own small calls
    env, shapes = Harvest(), []
    params = make_params().replace(max_steps=3)
    host = HostPolicy(lambda obs: shapes.append(obs.shape[0]) or np.zeros(obs.shape[0], int), env.num_actions)
    evaluate(env, host, generate_maps(np.arange(9)), 8, jax.random.key(0), params)  # 72 episodes: two calls of 64
    assert set(shapes) == {64} and episodes_per_call(env) == 64 and episodes_per_call(RACING) == 256
    monkeypatch.setenv("WORLDAGENT_EPISODES_PER_CALL", "32")
    assert episodes_per_call(env) == episodes_per_call(RACING) == 32


def test_harvest_metrics_per_episode_and_per_agent():
    env = Harvest()
    params = make_params(can_tag=[True, False, False, False]).replace(max_steps=40)
    metrics = evaluate(env, scripted_policy("harvest", "random"), generate_maps(np.arange(3)), 4, jax.random.key(0), params)
    assert metrics["group_reward"].shape == (3, 4) and metrics["conflict"].shape == (3, 4)
    assert metrics["returns"].shape == (3, 4, 4)
    np.testing.assert_allclose(metrics["returns"].sum(-1), metrics["group_reward"], atol=1e-5)


def test_summary_is_the_mean_and_its_standard_error():
    summary = summarise({"x": np.array([[1.0, 3.0], [2.0, 2.0]])})
    np.testing.assert_allclose(summary["x"]["mean"], [2.0, 2.0])
    np.testing.assert_allclose(summary["x"]["sem"], [1.0, 0.0])


def test_bad_requests_get_clear_errors(worlds):
    with pytest.raises(WorldagentError, match="repeats=0"):
        evaluate(RACING, random_racing_policy(), worlds, 0, jax.random.key(0))
    one = jax.tree_util.tree_map(lambda leaf: leaf[0], worlds)
    with pytest.raises(WorldagentError, match="centreline has shape"):
        evaluate(RACING, random_racing_policy(), one, 2, jax.random.key(0))


@pytest.mark.integration
def test_sharding_over_two_devices_gives_the_metrics_of_one(tmp_path, worlds):
    """Five worlds (padded to six) over two forced host devices, in a fresh process."""
    import os
    import subprocess
    import sys

    want = evaluate(RACING, scripted_policy("racing", "driver"), jax.tree_util.tree_map(lambda leaf: leaf[:5], worlds), 2, jax.random.key(5))
    script = (
        "import jax, numpy as np\n"
        "from worldagent.agents.loaders import scripted_policy\n"
        "from worldagent.envs.racing.env import ParticleRacing\n"
        "from worldagent.envs.racing.tracks import generate_tracks\n"
        "from worldagent.evaluation.local import evaluate\n"
        "assert len(jax.devices()) == 2\n"
        "worlds = jax.tree_util.tree_map(lambda leaf: leaf[:5], generate_tracks(np.arange(6)))\n"
        "metrics = evaluate(ParticleRacing(), scripted_policy('racing', 'driver'), worlds, 2, jax.random.key(5))\n"
        f"np.savez({str(tmp_path / 'two.npz')!r}, **metrics)\n"
    )
    flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=2"  # the same compiler settings, two devices
    env = {**os.environ, "XLA_FLAGS": flags, "JAX_PLATFORMS": "cpu"}
    subprocess.run([sys.executable, "-c", script], check=True, env=env, timeout=300)
    with np.load(tmp_path / "two.npz") as two:
        assert set(two.files) == set(want)
        for name in want:
            np.testing.assert_array_equal(two[name], want[name])
