"""Harvest metrics on hand-computed cases (paper §6.2.2; Perolat et al. 2017)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from worldagent.envs.harvest.metrics import conflict, episode_metrics, equality, group_reward, peace, sustainability


@pytest.mark.parametrize(
    "returns, expected",
    [
        ([5, 5, 5, 5], 1.0),  # equal returns
        ([8, 0, 0, 0], 0.25),  # one of four takes all: 1 - 6*8 / (2*4*8)
        ([0, 0, 0, 0], 1.0),  # nobody scored
        ([1, 2, 3, 4], 1 - 20 / 80),  # sum |Ri - Rj| over ordered pairs = 20, 2N sum R = 80
        ([3, 1, 0, 0], 1 - 20 / 32),  # ordered pairs: 2 * (2 + 3 + 3 + 1 + 1)
    ],
)
def test_equality_is_one_minus_gini(returns, expected):
    assert float(equality(jnp.array(returns, jnp.float32))) == pytest.approx(expected)


def test_group_reward_and_batching():
    returns = jnp.array([[1.0, 2.0, 3.0, 4.0], [8.0, 0.0, 0.0, 0.0]])
    np.testing.assert_allclose(group_reward(returns), [10.0, 8.0])
    np.testing.assert_allclose(equality(returns), [0.75, 0.25])


def test_conflict_is_the_fraction_of_steps_with_someone_tagged_out():
    assert float(conflict(jnp.int32(250), jnp.int32(1000))) == pytest.approx(0.25)
    assert float(conflict(jnp.int32(0), jnp.int32(1000))) == 0.0
    assert float(conflict(jnp.int32(0), jnp.int32(0))) == 0.0


def test_sustainability_is_the_mean_collection_time():
    # agent 0 collected at t = 10 and 30 (mean 20); agent 1 at t = 40 (mean 40); the others never
    reward_time = jnp.array([40.0, 40.0, 0.0, 0.0])
    returns = jnp.array([2.0, 1.0, 0.0, 0.0])
    assert float(sustainability(reward_time, returns)) == pytest.approx(30.0)
    assert float(sustainability(jnp.zeros(4), jnp.zeros(4))) == 0.0


def test_peace_counts_untagged_agent_steps_per_step():
    assert float(peace(jnp.int32(4 * 100), jnp.int32(100))) == 4.0
    assert float(peace(jnp.int32(4 * 100 - 25), jnp.int32(100))) == pytest.approx(3.75)


def test_episode_metrics_gathers_them_all():
    metrics = episode_metrics(jnp.array([8.0, 0, 0, 0]), jnp.array([80.0, 0, 0, 0]), jnp.int32(10), jnp.int32(390), jnp.int32(100))
    assert set(metrics) == {"returns", "group_reward", "equality", "conflict", "sustainability", "peace"}
    assert float(metrics["group_reward"]) == 8.0 and float(metrics["equality"]) == pytest.approx(0.25)
    assert float(metrics["conflict"]) == pytest.approx(0.1) and float(metrics["peace"]) == pytest.approx(3.9)
    assert float(metrics["sustainability"]) == pytest.approx(10.0)
