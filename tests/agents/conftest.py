"""Small world sets and tiny PPO budgets, built once per test session."""

from __future__ import annotations

import pytest

from worldagent.agents.distributions import WorldPool, world_distribution
from worldagent.agents.ppo import PPOConfig
from worldagent.envs import registry

# Small enough to train in seconds on 2 CPU cores, large enough to learn something.
TINY_PPO = PPOConfig(total_episodes=64, num_envs=8, num_steps=32, num_minibatches=2, update_epochs=2, hidden=(32, 32))


@pytest.fixture(scope="session")
def racing_spec():
    return registry.get("racing")


@pytest.fixture(scope="session")
def racing_env(racing_spec):
    return racing_spec.make_env()[0]


@pytest.fixture(scope="session")
def racing_pool() -> WorldPool:
    """8 procedural tracks, drawn uniformly."""
    return world_distribution("racing", "generator", size=8, seed=0)


@pytest.fixture(scope="session")
def tiny_ppo() -> PPOConfig:
    return TINY_PPO
