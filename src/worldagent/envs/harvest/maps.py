"""The procedural map generator for Resource Harvest (paper §5.2.1), pure JAX and vmapped.

The paper's four steps, each a small function below:

1. ``corner_rectangles``: 0–4 regions, rectangles of random sizes grown from distinct corners;
2. ``merge_groups``: regions that overlap or touch merge into one (transitive closure);
3. ``bordering_walls`` + ``carve_entrances``: the border of every merged region becomes a wall
   (the grid edge needs none), and each merged region gets, with some probability, a one-cell
   entrance through a straight stretch of its wall;
4. ``apple_clusters``: every room (each region's interior and the open space outside) gets
   1–3 round clusters of apples.

Spawn corners are never walls (a corner is interior to the rectangle that contains it) and
never hold apples. Map ``i`` of ``generate_maps(seeds_from(SEED, n))`` is generated from the key
``jax.random.key(SEED + i)`` alone, so it does not depend on ``n`` or on the batch it is in.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.envs.harvest.world import DEFAULT_SIZE, HarvestMap, spawn_corners
from worldagent.errors import WorldagentError

NUM_CORNERS = 4
NUM_ROOMS = NUM_CORNERS + 1  # one per merged region (at most four) plus the open space
CHUNK = 1024  # maps per compiled call of generate_maps


@dataclasses.dataclass(frozen=True)
class MapConfig:
    """Settings of the generator.

    Attributes:
        size: side of the square grid, cells (25 by default).
        max_regions: regions per map are uniform in ``[0, max_regions]`` (the paper: 0–4).
        min_extent, max_extent: bounds of each region's height and width, wall included;
            ``max_extent`` defaults to ``size - 5``.
        entrance_probability: chance that a merged region gets an entrance ("optional").
        clusters_per_room: inclusive (min, max) apple clusters per room.
        cluster_radius: inclusive (min, max) Euclidean radius of a cluster, cells.
        apple_density: chance that each cell of a cluster holds an apple.
    """

    size: int = DEFAULT_SIZE
    max_regions: int = 4
    min_extent: int = 5
    max_extent: int | None = None
    entrance_probability: float = 0.5
    clusters_per_room: tuple[int, int] = (1, 3)
    cluster_radius: tuple[int, int] = (1, 2)
    apple_density: float = 0.9

    @property
    def extent_range(self) -> tuple[int, int]:
        """Inclusive (min, max) region side."""
        return self.min_extent, self.size - 5 if self.max_extent is None else self.max_extent

    def validate(self) -> None:
        """Raise ``WorldagentError`` for settings the generator cannot honour."""
        low, high = self.extent_range
        if self.size < 8:
            raise WorldagentError(f"map size {self.size} is too small; use a size of at least 8.")
        if not 0 <= self.max_regions <= NUM_CORNERS:
            raise WorldagentError(f"max_regions is {self.max_regions}; pick 0 to 4 (one region per corner).")
        if not 3 <= low <= high <= self.size:
            raise WorldagentError(f"region extents ({low}, {high}) must satisfy 3 <= min <= max <= size ({self.size}).")
        for name, (a, b) in (("clusters_per_room", self.clusters_per_room), ("cluster_radius", self.cluster_radius)):
            if not 0 <= a <= b:
                raise WorldagentError(f"{name} is ({a}, {b}); give an inclusive range 0 <= min <= max.")
        for name, p in (("entrance_probability", self.entrance_probability), ("apple_density", self.apple_density)):
            if not 0.0 <= p <= 1.0:
                raise WorldagentError(f"{name} is {p}; give a probability in [0, 1].")


def seeds_from(seed: int, n: int) -> np.ndarray:
    """int64[n]: the seeds ``seed, seed + 1, ..., seed + n - 1`` (map i uses seed + i)."""
    return np.arange(seed, seed + n, dtype=np.int64)


def uniform_int(u: jax.Array, low: int, high: int) -> jax.Array:
    """Integers uniform in [low, high] from uniforms ``u`` in [0, 1).

    The generator draws all its randomness with one ``uniform`` call per step: each random
    call costs a fraction of a second of XLA compile time on CPU.
    """
    return jnp.minimum(low + jnp.floor(u * (high - low + 1)).astype(jnp.int32), high)


def corner_rectangles(key: jax.Array, config: MapConfig) -> tuple[jax.Array, jax.Array]:
    """Step 1: ``(present bool[4], bounds int32[4, 4])``, bounds as [row0, row1, col0, col1) per corner."""
    u = jax.random.uniform(key, (1 + 3 * NUM_CORNERS,))
    size = config.size
    low, high = config.extent_range
    num_regions = uniform_int(u[0], 0, config.max_regions)
    rank = jnp.argsort(jnp.argsort(u[1 : 1 + NUM_CORNERS]))  # a random order of the corners
    present = rank < num_regions
    height = uniform_int(u[1 + NUM_CORNERS : 1 + 2 * NUM_CORNERS], low, high)
    width = uniform_int(u[1 + 2 * NUM_CORNERS :], low, high)
    return present, corner_bounds(height, width, size)


def corner_bounds(height: jax.Array, width: jax.Array, size: int) -> jax.Array:
    """int32[4, 4]: [row0, row1, col0, col1) of rectangles int32[4] high and wide grown from the corners TL, TR, BL, BR."""
    top, left = np.array([True, True, False, False]), np.array([True, False, True, False])
    row0 = jnp.where(top, 0, size - height)
    col0 = jnp.where(left, 0, size - width)
    return jnp.stack([row0, row0 + height, col0, col0 + width], axis=1)


def rectangle_masks(present: jax.Array, bounds: jax.Array, size: int) -> jax.Array:
    """bool[4, size, size]: the cells of each present rectangle."""
    cells = jnp.arange(size)
    rows = (cells[None, :] >= bounds[:, :1]) & (cells[None, :] < bounds[:, 1:2])
    cols = (cells[None, :] >= bounds[:, 2:3]) & (cells[None, :] < bounds[:, 3:4])
    return rows[:, :, None] & cols[:, None, :] & present[:, None, None]


def merge_groups(present: jax.Array, bounds: jax.Array) -> jax.Array:
    """Step 2: int32[4], each region's group, named by its lowest member; -1 where absent.

    Regions merge when they overlap or touch (also diagonally), so that different groups are
    always separated by at least one free cell and every group gets its own wall.
    """

    def near(start, stop):  # intervals [start, stop) within one cell of each other
        return (start[:, None] <= stop[None, :]) & (start[None, :] <= stop[:, None])

    linked = near(bounds[:, 0], bounds[:, 1]) & near(bounds[:, 2], bounds[:, 3])
    linked = linked & present[:, None] & present[None, :]
    for _ in range(2):  # paths of up to four regions: closure by repeated squaring
        linked = linked | (linked.astype(jnp.int32) @ linked.astype(jnp.int32) > 0)
    lowest = jnp.argmax(linked, axis=1)  # the first linked index; a present region links to itself
    return jnp.where(present, lowest, -1)


def neighbours(mask: jax.Array, fill: bool, offsets) -> jax.Array:
    """bool[K, H, W]: ``mask`` shifted by each (dr, dc) in ``offsets``, ``fill`` beyond the edge."""
    padded = jnp.pad(mask, 1, constant_values=fill)
    height, width = mask.shape
    return jnp.stack([padded[1 + dr : 1 + dr + height, 1 + dc : 1 + dc + width] for dr, dc in offsets])


RING = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0)]


def bordering_walls(union: jax.Array) -> jax.Array:
    """Step 3a: bool[H, W], the cells of the regions with a neighbour (of 8) outside them.

    Beyond the grid edge counts as inside, so the edge itself is never walled.
    """
    return union & ~neighbours(union, True, RING).all(axis=0)


def entrance_candidates(walls: jax.Array, group_masks: jax.Array) -> jax.Array:
    """bool[4, H, W]: each merged region's wall cells with its inside on one side and the outside opposite."""
    union = group_masks.any(axis=0)
    inside, outside = union & ~walls, ~union
    up, down, left, right = neighbours(inside, False, [(-1, 0), (1, 0), (0, -1), (0, 1)])
    out_up, out_down, out_left, out_right = neighbours(outside, False, [(-1, 0), (1, 0), (0, -1), (0, 1)])
    through = (up & out_down) | (out_up & down) | (left & out_right) | (out_left & right)
    return walls & through & group_masks


def carve_entrances(key: jax.Array, walls: jax.Array, group_masks: jax.Array, config: MapConfig) -> jax.Array:
    """Step 3b: bool[H, W], one entrance cell per merged region that gets one.

    An entrance is a wall cell with the region's inside on one side and the outside on the
    opposite side, so removing it always opens a passage.
    """
    candidates = entrance_candidates(walls, group_masks)
    u = jax.random.uniform(key, (NUM_CORNERS * (1 + candidates[0].size),))
    scores = jnp.where(candidates, u[NUM_CORNERS:].reshape(candidates.shape), -1.0)
    flat = scores.reshape(NUM_CORNERS, -1)
    chosen = jax.nn.one_hot(jnp.argmax(flat, axis=1), flat.shape[1], dtype=bool).reshape(candidates.shape)
    wanted = u[:NUM_CORNERS] < config.entrance_probability
    usable = wanted & candidates.any(axis=(1, 2))
    return (chosen & usable[:, None, None]).any(axis=0)


def apple_clusters(key: jax.Array, rooms: jax.Array, config: MapConfig) -> jax.Array:
    """Step 4: bool[H, W], round clusters of apples inside each room of ``rooms`` bool[R, H, W]."""
    num_rooms, height, width = rooms.shape
    least, most = config.clusters_per_room
    if most == 0:
        return jnp.zeros((height, width), bool)
    sizes = [num_rooms, num_rooms * most, num_rooms * most * height * width, height * width]
    u = jnp.split(jax.random.uniform(key, (sum(sizes),)), np.cumsum(sizes)[:-1])
    count = uniform_int(u[0], least, most)
    active = (jnp.arange(most)[None, :] < count[:, None]) & rooms.any(axis=(1, 2))[:, None]  # [R, C]
    scores = jnp.where(rooms[:, None], u[2].reshape(num_rooms, most, height, width), -1.0)
    centre = jnp.argmax(scores.reshape(num_rooms, most, -1), axis=-1)
    centre_row, centre_col = centre // width, centre % width
    radius = uniform_int(u[1].reshape(num_rooms, most), *config.cluster_radius)
    rows, cols = jnp.arange(height)[:, None], jnp.arange(width)[None, :]
    distance2 = (rows - centre_row[..., None, None]) ** 2 + (cols - centre_col[..., None, None]) ** 2
    discs = (distance2 <= (radius**2)[..., None, None]) & active[..., None, None] & rooms[:, None]
    filled = u[3].reshape(height, width) < config.apple_density
    return discs.any(axis=(0, 1)) & filled


class Layout(NamedTuple):
    """The walls of one map and how they came about (for tests and pictures)."""

    group_masks: jax.Array  # bool[4, H, W] cells of each merged region, by its lowest corner
    walls: jax.Array  # bool[H, W] bordering walls before the entrances are carved
    entrances: jax.Array  # bool[H, W] the carved entrance cells


def region_walls(present: jax.Array, bounds: jax.Array, size: int) -> tuple[jax.Array, jax.Array]:
    """Steps 2 and 3a for rectangles ``present`` bool[4], ``bounds`` int32[4, 4]: (group_masks bool[4, H, W], walls bool[H, W])."""
    rectangles = rectangle_masks(present, bounds, size)
    group = merge_groups(present, bounds)
    member = group[None, :] == jnp.arange(NUM_CORNERS)[:, None]  # [group, region]
    group_masks = (rectangles[None] & member[:, :, None, None]).any(axis=1)
    return group_masks, bordering_walls(rectangles.any(axis=0))


def generate_layout(key: jax.Array, config: MapConfig = MapConfig()) -> Layout:
    """Steps 1–3 of the generator: regions, merged groups, walls and entrances."""
    key_regions, key_entrances = jax.random.split(key)
    group_masks, walls = region_walls(*corner_rectangles(key_regions, config), config.size)
    return Layout(group_masks, walls, carve_entrances(key_entrances, walls, group_masks, config))


def generate_map(key: jax.Array, config: MapConfig = MapConfig()) -> HarvestMap:
    """One map from one key (pure JAX; vmap it over keys).

    Returns:
        ``HarvestMap`` with walls and apples bool[size, size].
    """
    key_layout, key_apples = jax.random.split(key)
    group_masks, walls, entrances = generate_layout(key_layout, config)
    outside = ~group_masks.any(axis=0)
    rooms = jnp.concatenate([group_masks & ~walls[None], outside[None]], axis=0)
    apples = apple_clusters(key_apples, rooms, config)
    corners = jnp.zeros((config.size, config.size), bool).at[tuple(spawn_corners(config.size, config.size).T)].set(True)
    return HarvestMap(walls=walls & ~entrances & ~corners, apples=apples & ~corners)


@functools.lru_cache(maxsize=8)
def _batched_generator(config: MapConfig):
    return jax.jit(jax.vmap(lambda seed: generate_map(jax.random.key(seed), config)))


def generate_maps(seeds, config: MapConfig = MapConfig()) -> HarvestMap:
    """A batch of maps, map ``i`` from seed ``seeds[i]`` alone.

    Args:
        seeds: int[B] non-negative seeds below 2**31 (see ``seeds_from``).
        config: generator settings.

    Returns:
        ``HarvestMap`` with walls and apples bool[B, size, size] (numpy arrays).
    """
    config.validate()
    seeds = np.asarray(seeds)
    if seeds.ndim != 1 or not np.issubdtype(seeds.dtype, np.integer):
        raise WorldagentError(f"seeds must be a 1-d array of integers; got shape {seeds.shape} of {seeds.dtype}.")
    if seeds.size and (seeds.min() < 0 or seeds.max() >= 2**31):
        raise WorldagentError("seeds must lie in [0, 2**31); pick a smaller seed.")
    generate = _batched_generator(config)
    chunks = []
    for start in range(0, len(seeds), CHUNK):  # few distinct batch shapes -> few compilations
        chunk = seeds[start : start + CHUNK]
        padded = np.zeros(max(64, 1 << (len(chunk) - 1).bit_length()), np.int32)
        padded[: len(chunk)] = chunk
        chunks.append(jax.tree_util.tree_map(lambda leaf, n=len(chunk): np.asarray(leaf)[:n], generate(padded)))
    if not chunks:
        return HarvestMap(walls=np.zeros((0, config.size, config.size), bool), apples=np.zeros((0, config.size, config.size), bool))
    return jax.tree_util.tree_map(lambda *leaves: np.concatenate(leaves), *chunks)
