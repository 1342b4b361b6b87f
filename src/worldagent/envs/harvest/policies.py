"""Reference policies for Resource Harvest: uniform random and a greedy apple-seeker.

Both follow the policy contract (DESIGN.md): ``act(policy_params, obs, key) -> action``, pure
JAX, with the agent axis: obs uint8[N, V, V, 4] -> action int32[N]. Neither has parameters, so
``policy_params`` is ignored (pass ``None``). They are baselines and test drivers.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from worldagent.envs.harvest.env import BACKWARD, FORWARD, LEFT, NUM_ACTIONS, RIGHT, ROTATE_RIGHT, Harvest

EXPLORE_ACTIONS = jnp.array([FORWARD, FORWARD, BACKWARD, LEFT, RIGHT, ROTATE_RIGHT], jnp.int32)


def random_act(policy_params, obs: jax.Array, key: jax.Array) -> jax.Array:
    """int32[N]: uniform over all 8 actions (TAG is a no-op for agents that may not tag)."""
    del policy_params
    return jax.random.randint(key, obs.shape[:1], 0, NUM_ACTIONS, dtype=jnp.int32)


def greedy_policy(env: Harvest = Harvest()):
    """``act(policy_params, obs, key)`` that moves each agent toward its nearest visible apple.

    Nearest is by Manhattan distance in the window (ties: the first in reading order, i.e.
    farthest ahead, then leftmost). It steps along the longer axis to the apple, or the
    shorter when that is blocked by a wall or agent; with no apple in view, or both blocked, it
    explores with a random move or turn. Tagged-out agents' actions are ignored by the env.
    """
    size, self_row, self_col = env.view_size, env.view_size - 1 - env.view_behind, env.view_size // 2

    def act_one(obs: jax.Array, key: jax.Array) -> jax.Array:
        rows, cols = jnp.meshgrid(jnp.arange(size), jnp.arange(size), indexing="ij")
        ahead, rightward = self_row - rows, cols - self_col
        distance = jnp.where(obs[..., 1] > 0, jnp.abs(ahead) + jnp.abs(rightward), 4 * size)
        nearest = jnp.argmin(distance)
        seen = distance.reshape(-1)[nearest] < 4 * size
        d_ahead, d_right = ahead.reshape(-1)[nearest], rightward.reshape(-1)[nearest]
        along = jnp.where(d_ahead > 0, FORWARD, BACKWARD)
        across = jnp.where(d_right > 0, RIGHT, LEFT)
        longer_is_along = jnp.abs(d_ahead) >= jnp.abs(d_right)
        first = jnp.where(longer_is_along, along, across)
        second = jnp.where(longer_is_along, across, along)
        second_useful = jnp.where(longer_is_along, d_right != 0, d_ahead != 0)
        # Cells one step forward, backward, left, right; the window is padded so none is missing.
        solid = jnp.pad((obs[..., 0] > 0) | (obs[..., 2] > 0), 1)
        blocked = jnp.zeros(NUM_ACTIONS, bool)
        for action, (dr, dc) in ((FORWARD, (-1, 0)), (BACKWARD, (1, 0)), (LEFT, (0, -1)), (RIGHT, (0, 1))):
            blocked = blocked.at[action].set(solid[1 + self_row + dr, 1 + self_col + dc])
        explore = jax.random.choice(key, EXPLORE_ACTIONS)
        chosen = jnp.where(~blocked[first], first, jnp.where(second_useful & ~blocked[second], second, explore))
        return jnp.where(seen, chosen, explore).astype(jnp.int32)

    def act(policy_params, obs: jax.Array, key: jax.Array) -> jax.Array:
        """int32[N] greedy actions for obs uint8[N, V, V, 4]."""
        del policy_params
        return jax.vmap(act_one)(obs, jax.random.split(key, obs.shape[0]))

    return act
