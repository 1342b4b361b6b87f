"""PPO and ACKTR's actor-critic refuses, in one line naming the fix, an observation that is not flat (issue 30, item 2)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import pytest

from worldagent.agents.networks import ActorCritic
from worldagent.errors import WorldagentError


def test_actor_critic_is_built_on_a_flat_observation_and_refuses_others():
    network = ActorCritic(4, (8,))
    params = network.init(jax.random.key(0), jnp.zeros(10))
    logits, value = network.apply(params, jnp.zeros((3, 10)))  # applied to batches as before
    assert logits.shape == (3, 4) and value.shape == (3,)
    for shape in ((5, 5), (5, 5, 2)):
        with pytest.raises(WorldagentError, match=r"PPO and ACKTR need a flat observation .* flatten it") as error:
            jax.jit(network.init)(jax.random.key(0), jnp.zeros(shape))
        assert "\n" not in str(error.value) and str(shape) in str(error.value)
