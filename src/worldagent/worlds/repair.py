"""Repair: turn decoded cell probabilities into valid worlds (paper §4.2, §5.2.1).

Racing (the paper's rule): map the decoded raster to the most similar track of the dataset.
"Most similar" is the dataset track the decoder finds most probable: with Bernoulli logits
``l``, ``log p(x_i | l) = x_i·l - Σ softplus(l)``, so the best track is ``argmax_i x_i·l``, one
matrix product with the dataset's rasters, exact and batched on device. Given a track's own
raster as (confident) logits, the track itself wins unless a duplicate exists.

Harvest: walls where the wall logit is positive; the spawn corners always free; exactly K
apples on the K free cells with the highest apple logits (the paper keeps the number of
resources the same across worlds). If fewer than K non-corner cells are free, the walls with
the lowest logits are cleared to make room, so any input yields a valid map.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.envs.harvest.world import HarvestMap, spawn_corners

LOGIT_CLIP = 1e4  # keeps the harvest priorities below apart from the wall offset
WALL_OFFSET = 1e6


def nearest_track(logits: jax.Array, rasters: jax.Array) -> jax.Array:
    """i32[B]: index of the dataset raster most probable under each row of logits.

    Args:
        logits: f32[B, D] decoded Bernoulli logits.
        rasters: f32[N, D] the dataset's rasters (0/1).
    """
    return jnp.argmax(logits @ rasters.T, axis=-1).astype(jnp.int32)


def repair_harvest(logits: jax.Array, apples: int) -> HarvestMap:
    """Valid maps with exactly ``apples`` apples and free spawn corners from decoded logits.

    Args:
        logits: f32[2, H, W] (or [B, 2, H, W]) wall and apple logits.
        apples: K, the number of apples every map gets.

    Returns:
        ``HarvestMap`` with bool walls and apples of shape [H, W] (or [B, H, W]).
    """
    if logits.ndim == 4:
        return jax.vmap(lambda one: repair_harvest(one, apples))(logits)
    wall_logit, apple_logit = jnp.clip(logits[0], -LOGIT_CLIP, LOGIT_CLIP), jnp.clip(logits[1], -LOGIT_CLIP, LOGIT_CLIP)
    height, width = wall_logit.shape
    corners = jnp.zeros((height, width), bool).at[tuple(spawn_corners(height, width).T)].set(True)
    walls = (wall_logit > 0) & ~corners
    # Free cells first, by apple logit; then wall cells, least confident walls first; never corners.
    priority = jnp.where(walls, -WALL_OFFSET - wall_logit, apple_logit)
    priority = jnp.where(corners, -jnp.inf, priority).reshape(-1)
    _, chosen = jax.lax.top_k(priority, apples)
    apple_cells = jnp.zeros(height * width, bool).at[chosen].set(True).reshape(height, width)
    return HarvestMap(walls=walls & ~apple_cells, apples=apple_cells)


def threshold_harvest(logits: np.ndarray) -> HarvestMap:
    """The unrepaired decode: walls and apples where their logits are positive ([B, 2, H, W])."""
    logits = np.asarray(logits)
    return HarvestMap(walls=logits[:, 0] > 0, apples=logits[:, 1] > 0)
