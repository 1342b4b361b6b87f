"""Harvest's repair step: decoded cell logits -> a valid map (paper §5.2.1).

Walls. By default (``walls="nearest"``) the wall grid is the dataset's wall layout the decoder
finds most probable (``envs.repairs.nearest_index``, racing's rule applied to the wall channel
alone). The decoder's wall channel is blurry: a wall line it is unsure of comes out as a row of
logits near zero, and thresholding them (``walls="threshold"``) leaves broken walls that
enclose nothing. Snapping to a dataset layout keeps the procedural generator's closed rooms,
so worlds in which walls cut the tagger off from the others (the paper's Figure 8b) occur as
often in G(z) as the decoder's wall signal allows. Measured with ``worldagent generator report``
(``structure.tagger_separated``); numbers in ``docs/harvest.md``. Snapping is closed: G(z) returns
dataset layouts only; ``open_repair.OpenRooms`` returns new layouts the generator could make.

Apples. By default exactly K apples on the K free cells with the highest apple logits (the paper
keeps the number of resources the same across worlds); the spawn corners are always free. If fewer
than K non-corner cells are free, the walls with the lowest logits are cleared to make room, so any
input yields a valid map. ``apples="spread"`` (or ``"clusters"``, without its spacing and fitted
shift) places them as the procedural generator does instead (``apples.placed_apples``: 1-3 round
clusters per room, read off the apple logits; the rooms of the wall layout from
``apples.rooms_from_walls``), so the count varies as fresh maps' does.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from worldagent.envs.harvest.apples import CLUSTER_RULES, SPREAD, fit_shift, placed_apples, rooms_from_walls
from worldagent.envs.harvest.world import HarvestMap, spawn_corners
from worldagent.envs.repairs import nearest_index
from worldagent.errors import WorldagentError

LOGIT_CLIP = 1e4  # keeps the priorities below apart from the wall offset
WALL_OFFSET = 1e6
WALL_RULES = ("nearest", "threshold")


def corner_mask(height: int, width: int) -> np.ndarray:
    """bool[H, W]: the four spawn corners."""
    mask = np.zeros((height, width), bool)
    mask[tuple(spawn_corners(height, width).T)] = True
    return mask


def repaired_walls(wall_logit: jax.Array, layouts: jax.Array | None) -> jax.Array:
    """bool[H, W]: the dataset layout f32[L, H·W] most probable under ``wall_logit`` f32[H, W] (clipped), or the
    positive logits (``layouts`` None)."""
    if layouts is None:
        return wall_logit > 0
    return layouts[nearest_index(wall_logit.reshape(1, -1), layouts)[0]].reshape(wall_logit.shape) > 0.5


def repair_maps(logits: jax.Array, apples: int | str, layouts: jax.Array | None = None, shift: float | None = None) -> HarvestMap:
    """Valid maps with ``apples`` apples and free spawn corners from decoded logits.

    Args:
        logits: f32[2, H, W] (or [B, 2, H, W]) wall and apple logits.
        apples: K, the number of apples every map gets, or ``"spread"`` / ``"clusters"`` (``apples.placed_apples``).
        layouts: f32[L, H·W] 0/1 wall layouts to snap the walls to (the most probable one under
            the wall logits); None: walls where the wall logit is positive.
        shift: the apple logits' shift of ``"spread"`` (None: none).

    Returns:
        ``HarvestMap`` with bool walls and apples of shape [H, W] (or [B, H, W]).
    """
    if logits.ndim == 4:
        return jax.vmap(lambda one: repair_maps(one, apples, layouts, shift))(logits)
    wall_logit, apple_logit = jnp.clip(logits[0], -LOGIT_CLIP, LOGIT_CLIP), jnp.clip(logits[1], -LOGIT_CLIP, LOGIT_CLIP)
    walls = repaired_walls(wall_logit, layouts)
    if isinstance(apples, int):
        return place_apples(walls, wall_logit, apple_logit, apples)
    walls = walls & ~jnp.asarray(corner_mask(*walls.shape))
    return HarvestMap(walls=walls, apples=placed_apples(rooms_from_walls(walls), apple_logit, apples, shift))


def place_apples(walls: jax.Array, wall_logit: jax.Array, apple_logit: jax.Array, apples: int) -> HarvestMap:
    """The apple step of every harvest repair: exactly ``apples`` apples, free spawn corners.

    Args:
        walls: bool[H, W] the repaired walls.
        wall_logit, apple_logit: f32[H, W] decoded logits, clipped to ``LOGIT_CLIP``.
        apples: K, the number of apples.

    Returns:
        ``HarvestMap`` with bool walls and apples [H, W]: apples on the K free non-corner cells
        with the highest apple logits; where fewer are free, on the walls with the lowest logits
        (those walls are cleared).
    """
    height, width = walls.shape
    corners = jnp.asarray(corner_mask(height, width))
    walls = walls & ~corners
    # Free cells first, by apple logit; then wall cells, least confident walls first; never corners.
    priority = jnp.where(walls, -WALL_OFFSET - wall_logit, apple_logit)
    priority = jnp.where(corners, -jnp.inf, priority).reshape(-1)
    _, chosen = jax.lax.top_k(priority, apples)
    apple_cells = jnp.zeros(height * width, bool).at[chosen].set(True).reshape(height, width)
    return HarvestMap(walls=walls & ~apple_cells, apples=apple_cells)


def apple_setting(value, grid: tuple[int, int], worlds: HarvestMap) -> int | str:
    """The ``apples`` setting of a harvest repair, checked: ``"spread"``, ``"clusters"``, or K from 1 to the
    non-corner cells (None: the median count of ``worlds``, the dataset's)."""
    if value in CLUSTER_RULES:
        return value
    count = median_apples(worlds) if value is None else value
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)):
        raise ValueError(f"apples is a count K, {SPREAD!r} or 'clusters' (as the generator places them)")  # make_repair names the setting
    free = int(np.prod(grid)) - 4
    if not 1 <= count <= free:
        raise WorldagentError(f"apples={count}; pick between 1 and {free} (the non-corner cells of the map), or {SPREAD}.")
    return int(count)


def shift_setting(value, name: str = "apple_shift") -> float | None:
    """A logit shift setting ``name``, checked: a finite number, or None (fitted when the generator is made)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise WorldagentError(f"{name}={value!r}; give a number (a logit shift), or leave it out to fit it when the generator is made.")
    return float(value)


def threshold_maps(logits) -> HarvestMap:
    """The unrepaired decode: walls and apples where their logits are positive ([B, 2, H, W])."""
    logits = np.asarray(logits)
    return HarvestMap(walls=logits[:, 0] > 0, apples=logits[:, 1] > 0)


def median_apples(worlds: HarvestMap) -> int:
    """The median apple count of a batch of maps (the default K of the repair)."""
    apples = np.asarray(worlds.apples)
    return int(np.median(apples.reshape(len(apples), -1).sum(axis=1)))


def mean_apples(worlds: HarvestMap) -> float:
    """The mean apple count of a batch of maps (what a fitted ``apple_shift`` matches)."""
    apples = np.asarray(worlds.apples)
    return float(apples.reshape(len(apples), -1).sum(axis=1).mean())


def wall_layouts(worlds: HarvestMap) -> np.ndarray:
    """f32[L, H·W]: the distinct wall grids of a batch of maps, 0/1."""
    walls = np.asarray(worlds.walls, bool)
    return np.unique(walls.reshape(len(walls), -1), axis=0).astype(np.float32)


@struct.dataclass
class HarvestRepair:
    """G's repair for harvest: snapped (or thresholded) walls, exactly ``apples`` apples, free spawn corners.

    Attributes:
        layouts: f32[L, H·W] the dataset's distinct wall layouts (``walls="nearest"``), or None.
        apples: K, the apple count of every generated map, or ``"spread"`` / ``"clusters"`` (static).
        grid: (H, W) of the maps (static).
        apple_shift: the apple logits' shift of ``"spread"`` (``fitted``; None: not fitted, no shift) (static).
    """

    layouts: jax.Array | None
    apples: int | str = struct.field(pytree_node=False)
    grid: tuple = struct.field(pytree_node=False)
    apple_shift: float | None = struct.field(pytree_node=False, default=None)

    @classmethod
    def from_dataset(cls, dataset, config=None) -> HarvestRepair:
        """The repair for maps like ``dataset``'s.

        ``config``: ``apples`` K (default: the dataset's median count), "spread" or "clusters" (as the
        generator places them); ``apple_shift`` of "spread" (default: fitted when the generator is made);
        ``walls`` "nearest" (default: the dataset layout the decoder finds most probable) or "threshold".
        """
        config = dict(config or {})
        unknown = set(config) - {"apples", "apple_shift", "walls"}
        if unknown:
            raise WorldagentError(
                f"unknown harvest repair setting(s) {sorted(unknown)}; use apples=K|spread|clusters, apple_shift=X and walls=nearest|threshold."
            )
        grid = tuple(int(s) for s in dataset.cell_shape[1:])
        count = apple_setting(config.get("apples") or None, grid, dataset.worlds)  # 0 in old generator.json files: the default
        rule = config.get("walls", "nearest")
        if rule not in WALL_RULES:
            raise WorldagentError(f"walls={rule!r}; pick one of {', '.join(WALL_RULES)}.")
        layouts = jnp.asarray(wall_layouts(dataset.worlds)) if rule == "nearest" else None
        return cls(layouts, count, grid, shift_setting(config.get("apple_shift")))

    @property
    def config(self) -> dict:
        shift = {"apple_shift": self.apple_shift} if self.apples == SPREAD else {}
        return {"apples": self.apples, **shift, "walls": "threshold" if self.layouts is None else "nearest"}

    def fitted(self, logits: jax.Array, worlds: HarvestMap) -> HarvestRepair:
        """This repair with ``apple_shift`` fitted on decoded logits f32[B, 2·H·W] of the prior (``apples.fit_shift``)
        so that they hold the dataset ``worlds``' mean apple count; itself unless its apples are "spread" and no shift is set."""
        if self.apples != SPREAD or self.apple_shift is not None:
            return self
        grids = jnp.clip(logits.reshape(-1, 2, *self.grid), -LOGIT_CLIP, LOGIT_CLIP)
        corners = jnp.asarray(corner_mask(*self.grid))
        rooms = jax.jit(jax.vmap(lambda wall_logit: rooms_from_walls(repaired_walls(wall_logit, self.layouts) & ~corners)))(grids[:, 0])
        return self.replace(apple_shift=fit_shift(rooms, grids[:, 1], mean_apples(worlds)))

    def __call__(self, logits: jax.Array) -> HarvestMap:
        """Valid maps from decoded logits f32[B, 2·H·W]."""
        return repair_maps(logits.reshape(-1, 2, *self.grid), self.apples, self.layouts, self.apple_shift)
