"""Per-episode metrics of Resource Harvest (paper §6.2.2; Perolat et al. 2017, the paper's [27]).

Each metric is a small pure function of per-episode accumulators that the env keeps in its
state, so evaluation never stores trajectories. All accept a leading batch axis.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def group_reward(returns: jax.Array) -> jax.Array:
    """Sum of the agents' returns, the paper's main harvest metric: U = Σᵢ Rᵢ.

    Args:
        returns: f32[..., N] each agent's episode return.

    Returns:
        f32[...].
    """
    return returns.sum(axis=-1)


def equality(returns: jax.Array) -> jax.Array:
    """1 − Gini: E = 1 − ΣᵢΣⱼ|Rᵢ − Rⱼ| / (2N ΣᵢRᵢ), and 1 when nobody scored (§6.2.2).

    Equal returns give 1; one of N agents taking everything gives 1/N.

    Args:
        returns: f32[..., N] non-negative episode returns.

    Returns:
        f32[...] in [0, 1].
    """
    returns = returns.astype(jnp.float32)
    num_agents = returns.shape[-1]
    total = returns.sum(axis=-1)
    spread = jnp.abs(returns[..., :, None] - returns[..., None, :]).sum(axis=(-2, -1))
    safe_total = jnp.where(total > 0, total, 1.0)
    return jnp.where(total > 0, 1.0 - spread / (2.0 * num_agents * safe_total), 1.0)


def conflict(conflict_steps: jax.Array, steps: jax.Array) -> jax.Array:
    """Fraction of steps in which at least one agent was tagged out: C = (1/T) Σₜ 1[∃i out at t].

    The paper's "average number of steps in an episode where agents are tagged out", scaled
    to [0, 1]. 0 for an episode of no steps.

    Args:
        conflict_steps: int[...] steps that ended with at least one agent tagged out.
        steps: int[...] steps T in the episode.

    Returns:
        f32[...] in [0, 1].
    """
    return conflict_steps / jnp.maximum(steps, 1).astype(jnp.float32)


def sustainability(reward_time: jax.Array, returns: jax.Array) -> jax.Array:
    """Mean time at which rewards were collected (Perolat): S = mean over scoring i of tᵢ.

    tᵢ = Σₜ t·rᵢₜ / Σₜ rᵢₜ is agent i's average collection time (t = 1, 2, ... in steps).
    Agents that collected nothing are left out of the mean; 0 when nobody scored.

    Args:
        reward_time: f32[..., N] Σₜ t·rᵢₜ.
        returns: f32[..., N] Σₜ rᵢₜ.

    Returns:
        f32[...] in steps.
    """
    scored = returns > 0
    mean_time = reward_time / jnp.where(scored, returns, 1.0)
    count = scored.sum(axis=-1)
    return jnp.where(count > 0, (mean_time * scored).sum(axis=-1) / jnp.maximum(count, 1), 0.0)


def peace(untagged_agent_steps: jax.Array, steps: jax.Array) -> jax.Array:
    """Untagged agent-steps per step (Perolat): P = (1/T) Σₜ Σᵢ 1[i on the map at t].

    Args:
        untagged_agent_steps: int[...] agent-steps that ended on the map.
        steps: int[...] steps T in the episode.

    Returns:
        f32[...] in [0, N]; N means nobody was ever tagged out.
    """
    return untagged_agent_steps / jnp.maximum(steps, 1).astype(jnp.float32)


def episode_metrics(returns, reward_time, conflict_steps, untagged_agent_steps, steps) -> dict[str, jax.Array]:
    """All metrics of an episode from its accumulators (shapes as in the functions above).

    Returns:
        dict of ``returns`` f32[..., N] and f32[...] ``group_reward``, ``equality``,
        ``conflict``, ``sustainability`` (steps) and ``peace`` (agents).
    """
    return {
        "returns": returns,
        "group_reward": group_reward(returns),
        "equality": equality(returns),
        "conflict": conflict(conflict_steps, steps),
        "sustainability": sustainability(reward_time, returns),
        "peace": peace(untagged_agent_steps, steps),
    }
