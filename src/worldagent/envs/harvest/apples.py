"""Apples as the generator places them: decoded apple logits -> round clusters, room by room.

Why. The top-K rule (``repair.place_apples``) puts exactly K apples on the K cells with the
highest apple logits. The procedural generator (``maps.apple_clusters``) does something else: every
room (each merged region's interior, and the open space outside) gets 1-3 round clusters of
radius 1-2, each cell of a cluster holding an apple with probability 0.9; the apple count varies
with the rooms (8-54 on fresh maps, 5-95 %). On a trained generator's decodes the top-K rule
leaves single cells and streaks where the decoder is unsure, and every map gets the same count.

The rule here (``cluster_apples``) is the generator's, with its draws read off the apple logits
``l``. In a cluster a cell holds an apple with probability 0.9, so covering a cell changes the map's
log-probability under the decoder by ``log(0.9·e^l + 0.1)`` (``cell_gain``):

1. each room gets the generator's least number of clusters (1): the centre and radius whose disc,
   clipped to the room as the generator clips it, gains most;
2. then, greedily, the cluster (centre, radius, room) that gains most over the cells no cluster
   covers yet, while that gain is positive and its room has fewer than the generator's most (3).
   The generator's prior over counts and centres is flat, so the likelihood alone decides;
3. radii: the generator draws them uniformly, but the decoder blurs a cluster's rim, and by
   likelihood 74 % of the clusters got the smaller radius (the apple count 22 against fresh
   maps' 28, quick VAE). So a cluster gets the larger radius where its rim (the larger disc less
   the smaller) gains, and the half of a map's clusters whose rims gain most get it regardless;
4. the union of the discs holds ``round(0.9 · cells)`` apples (the generator's density in
   expectation) on its cells with the highest logits: the generator's holes are random, a decoder
   cannot know where they are, so they go where it is least sure; spawn corners are cleared, as
   the generator clears them.

``apples="spread"`` (the open repair's default; the nearest repair takes it too when asked)
changes two things, both because a VAE's apple logits are blurrier than the generator's clusters:

- step 2 takes only clusters that keep a free cell between them and the clusters found (no
  overlap, no touching): the decoder smears a cluster over more cells than its disc, and with
  touching allowed the greedy step spent its clusters on that smear's rim. Fresh maps' clusters
  merge into fewer patches by chance; a decoder cannot know where, so the rule keeps them apart;
- the apple logits are shifted by one constant per generator (``apple_shift``), fitted once when
  the generator is made (``fit_shift``: decodes of the prior get the dataset's mean apple count).
  The most probable placement under logits that are unsure everywhere is too few clusters: on
  the quick preset's 20-epoch VAE the ``clusters`` rule left 10.8 apples a map against fresh
  maps' 28.3, in 1.6 patches against 3.6, and a spawn walked 14.7 cells to its nearest apple
  against 9.8. Spread (shift 1.61): 28.7 apples, 3.1 patches, 9.6 cells; the patches stay 13 %
  short because that VAE's walls hold 1.5 rooms a map against fresh maps' 2.3, and a room takes
  at most 3 clusters. On the fidelity benchmark's 100-epoch VAE (shift 0.68) count, patches,
  patch size and that walk are within 7 % of fresh maps' (``clusters``: -8 %, -17 %, +10 %,
  +10 %; ``benchmarks/harvest_repair_fidelity.py``, docs/open-worlds.md).

``clusters`` stays what generators saved with it record, so they decode as they did.

Deterministic, a pure function of one map's logits and rooms (no batch-mates, no random key), and
jittable: a fixed number of greedy steps (rooms × the most clusters), each a few shifted sums over
the grid; under a millisecond a map on a CPU core. Measured against fresh maps in
``benchmarks/harvest_repair_fidelity.py`` (docs/generator.md).

``rooms_from_walls`` finds the rooms of a wall grid that does not say how it was built (the
nearest repair's dataset layouts, thresholded walls): the free cells' 4-connected areas once each
entrance (a one-cell gap in a straight wall) is closed, as the generator's rooms exclude them.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.envs.harvest.maps import NUM_ROOMS, MapConfig
from worldagent.envs.harvest.world import spawn_corners

CLUSTERS = "clusters"  # the ``apples`` setting that selects this rule (an integer K selects top-K)
SPREAD = "spread"  # clusters kept apart, logits shifted by the generator's fitted ``apple_shift`` (module doc)
CLUSTER_RULES = (CLUSTERS, SPREAD)
SHIFT_RANGE = (-8.0, 8.0)  # where ``fit_shift`` looks: past +-8 a logit of the clip range decides alone
SHIFT_STEPS = 12  # bisection steps: the range / 2**12 = 0.004 logits; each step places 256 maps' apples (~1 s on 2 cores)


def disc_offsets(radius: int) -> list[tuple[int, int]]:
    """The (dr, dc) offsets within Euclidean ``radius`` of a cell (the generator's disc, ``maps.apple_clusters``)."""
    return [(dr, dc) for dr in range(-radius, radius + 1) for dc in range(-radius, radius + 1) if dr * dr + dc * dc <= radius * radius]


def disc_sums(values: jax.Array, radius: int) -> jax.Array:
    """f32[..., H, W]: at each centre, the sum of ``values`` f32[..., H, W] over its disc (nothing beyond the edge)."""
    height, width = values.shape[-2:]
    pad = [(0, 0)] * (values.ndim - 2) + [(radius, radius), (radius, radius)]
    padded = jnp.pad(values, pad)
    return sum(padded[..., radius + dr : radius + dr + height, radius + dc : radius + dc + width] for dr, dc in disc_offsets(radius))


def disc_of(centre: jax.Array, radius: jax.Array, height: int, width: int) -> jax.Array:
    """bool[H, W]: the cells within ``radius`` of flat cell index ``centre``."""
    rows, cols = jnp.arange(height)[:, None], jnp.arange(width)[None, :]
    return (rows - centre // width) ** 2 + (cols - centre % width) ** 2 <= radius**2


def cell_gain(apple_logit: jax.Array, density: float) -> jax.Array:
    """f32[H, W]: what covering each cell with a cluster adds to the map's log-probability.

    The decoder's logit is the log-odds of an apple; in a cluster a cell holds one with probability
    ``density``: ``log(density · e^l + (1 - density))``. A cell the decoder is sure is empty costs at
    most ``-log(1 - density)`` (the generator's holes), one it finds an apple on gains about ``l``.
    """
    return jnp.logaddexp(apple_logit + np.log(density), np.log1p(-density))


class Clusters(NamedTuple):
    """The clusters ``choose_clusters`` finds in one map, in the order found; unused slots have centre -1."""

    centre: jax.Array  # int32[N] flat cell index of each cluster's centre, -1 for an unused slot
    room: jax.Array  # int32[N] the room it lies in
    ring: jax.Array  # f32[N] what growing it from the smallest radius to the largest adds to the log-probability


def choose_clusters(rooms: jax.Array, apple_logit: jax.Array, config: MapConfig = MapConfig(), apart: bool = False) -> Clusters:
    """The clusters the apple logits find most probable, room by room (steps 1 and 2 of the module doc).

    Args:
        rooms: bool[R, H, W] the rooms (disjoint; an empty one gets no cluster).
        apple_logit: f32[H, W] decoded apple logits.
        config: the generator's settings (``clusters_per_room``, ``cluster_radius``, ``apple_density``).
        apart: step 2 takes only clusters that neither overlap nor touch those found (``apples="spread"``).
    """
    num_rooms, height, width = rooms.shape
    least, most = config.clusters_per_room
    radii = tuple(range(config.cluster_radius[0], config.cluster_radius[1] + 1))
    present = rooms.any(axis=(1, 2))
    gain_per_cell = cell_gain(apple_logit, config.apple_density)
    in_room = jnp.where(rooms, gain_per_cell[None], 0.0)
    ring = (disc_sums(in_room, radii[-1]) - disc_sums(in_room, radii[0])).reshape(num_rooms, -1)  # [R, C]

    def step(state, slot):
        covered, count, found = state
        gained = jnp.where(rooms & ~covered[None], gain_per_cell[None], 0.0)  # [R, H, W]: each room's uncovered cells
        gain = jnp.stack([disc_sums(gained, radius) for radius in radii], axis=1)  # [R, K, H, W], clipped to the room
        must = present & (count < least)
        allowed = jnp.where(must.any(), must, present & (count < most))
        if apart:  # a disc that reaches a found cluster's cells or their 8 neighbours is out (a room's first is never)
            near = jnp.where(rooms & grown(covered)[None], 1.0, 0.0)
            touching = jnp.stack([disc_sums(near, radius) for radius in radii], axis=1) > 0
            gain = jnp.where(touching & ~must.any(), -jnp.inf, gain)
        gain = jnp.where(allowed[:, None, None, None] & rooms[:, None], gain, -jnp.inf).reshape(-1)
        best = jnp.argmax(gain)
        room, kind, centre = jnp.unravel_index(best, (num_rooms, len(radii), height * width))
        take = must.any() | (gain[best] > 0)
        covered = covered | (disc_of(centre, jnp.asarray(radii)[kind], height, width) & rooms[room] & take)
        found = Clusters(
            found.centre.at[slot].set(jnp.where(take, centre, -1)),
            found.room.at[slot].set(room),
            found.ring.at[slot].set(jnp.where(take, ring[room, centre], -jnp.inf)),
        )
        return (covered, count.at[room].add(take.astype(count.dtype)), found), None

    slots = num_rooms * most
    empty = Clusters(jnp.full(slots, -1, jnp.int32), jnp.zeros(slots, jnp.int32), jnp.full(slots, -jnp.inf, jnp.float32))
    start = (jnp.zeros((height, width), bool), jnp.zeros(num_rooms, jnp.int32), empty)
    return jax.lax.scan(step, start, jnp.arange(slots))[0][2]


def grown(mask: jax.Array) -> jax.Array:
    """bool[H, W]: ``mask`` and its cells' 8 neighbours."""
    padded = jnp.pad(mask, 1)
    height, width = mask.shape
    return functools.reduce(jnp.logical_or, [padded[1 + dr : 1 + dr + height, 1 + dc : 1 + dc + width] for dr in (-1, 0, 1) for dc in (-1, 0, 1)])


def cluster_radii(clusters: Clusters, config: MapConfig = MapConfig()) -> jax.Array:
    """int32[N]: each cluster's radius (step 3 of the module doc): the larger radius for every cluster whose rim
    gains, and for the half of the clusters whose rims gain most.

    Generators with more than two radii get the smallest or the largest.
    """
    low, high = config.cluster_radius
    used = clusters.centre >= 0
    count = used.sum()
    rank = jnp.argsort(jnp.argsort(-jnp.where(used, clusters.ring, -jnp.inf), stable=True), stable=True)
    large = (rank < count // 2) | (clusters.ring > 0)
    return jnp.where(large & used, high, low).astype(jnp.int32)


def cluster_discs(rooms: jax.Array, apple_logit: jax.Array, config: MapConfig = MapConfig(), apart: bool = False) -> jax.Array:
    """bool[H, W]: the union of the clusters ``choose_clusters`` finds, grown to ``cluster_radii``, each clipped to its room."""
    height, width = apple_logit.shape
    clusters = choose_clusters(rooms, apple_logit, config, apart)
    radius = cluster_radii(clusters, config)
    discs = jax.vmap(lambda centre, r: disc_of(jnp.maximum(centre, 0), r, height, width))(clusters.centre, radius)
    return (discs & rooms[clusters.room] & (clusters.centre >= 0)[:, None, None]).any(axis=0)


def fill_clusters(discs: jax.Array, apple_logit: jax.Array, density: float = MapConfig().apple_density) -> jax.Array:
    """bool[H, W]: ``round(density · cells)`` apples on the cells of ``discs`` bool[H, W] with the highest apple logits, corners cleared."""
    height, width = discs.shape
    flat = discs.reshape(-1)
    wanted = jnp.round(density * flat.sum()).astype(jnp.int32)
    order = jnp.argsort(-jnp.where(flat, apple_logit.reshape(-1), -jnp.inf), stable=True)
    rank = jnp.zeros(flat.size, jnp.int32).at[order].set(jnp.arange(flat.size, dtype=jnp.int32))
    apples = (flat & (rank < wanted)).reshape(height, width)
    corners = np.zeros((height, width), bool)
    corners[tuple(spawn_corners(height, width).T)] = True
    return apples & ~corners


def cluster_apples(rooms: jax.Array, apple_logit: jax.Array, config: MapConfig = MapConfig(), apart: bool = False) -> jax.Array:
    """bool[H, W]: apples placed by the generator's cluster rule, its draws read off ``apple_logit`` f32[H, W].

    Args:
        rooms: bool[R, H, W] the map's rooms (apples never leave them: walls and entrances stay free of apples).
        apple_logit: f32[H, W] decoded apple logits.
        config: the generator's settings.
        apart: clusters beyond each room's first neither overlap nor touch (``choose_clusters``).
    """
    return fill_clusters(cluster_discs(rooms, apple_logit, config, apart), apple_logit, config.apple_density)


def placed_apples(rooms: jax.Array, apple_logit: jax.Array, rule: str, shift: float | None = None) -> jax.Array:
    """bool[H, W]: apples by ``rule`` ("clusters" or "spread", ``CLUSTER_RULES``); "spread" shifts the logits by ``shift`` (None: 0, unfitted)."""
    if rule == SPREAD:
        return cluster_apples(rooms, apple_logit + (0.0 if shift is None else shift), apart=True)
    return cluster_apples(rooms, apple_logit)


@jax.jit
def _mean_spread_count(shift: float, rooms: jax.Array, apple_logit: jax.Array) -> jax.Array:
    """The mean apple count of ``placed_apples(..., "spread", shift)`` over a batch (arguments, not constants: no folding)."""
    return jax.vmap(lambda r, a: placed_apples(r, a, SPREAD, shift).sum())(rooms, apple_logit).mean()


def fit_shift(rooms: jax.Array, apple_logit: jax.Array, target: float) -> float:
    """The logit shift with which ``apples="spread"`` gives maps ``target`` apples on average (bisection).

    Args:
        rooms: bool[B, R, H, W] the rooms of B decodes of the prior, as the repair finds them.
        apple_logit: f32[B, H, W] their apple logits (clipped as the repair clips them).
        target: the mean apple count wanted (the dataset's).
    """
    # more shift, more clusters gain: the count grows with it (up to greedy ties)
    return bisect(lambda shift: float(_mean_spread_count(shift, rooms, apple_logit)), target, SHIFT_RANGE, SHIFT_STEPS)


def bisect(measure, target: float, bounds: tuple[float, float], steps: int) -> float:
    """The x within ``bounds`` where ``measure(x)``, growing with x, meets ``target``: ``steps`` halvings, to 0.001."""
    low, high = bounds
    for _ in range(steps):
        middle = (low + high) / 2
        low, high = (middle, high) if measure(middle) < target else (low, middle)
    return round((low + high) / 2, 3)


def _shift(mask: jax.Array, dr: int, dc: int, fill: bool) -> jax.Array:
    """``mask`` bool[H, W] moved so that cell (r, c) holds (r + dr, c + dc); ``fill`` beyond the edge."""
    height, width = mask.shape
    padded = jnp.pad(mask, 1, constant_values=fill)
    return padded[1 + dr : 1 + dr + height, 1 + dc : 1 + dc + width]


def entrances_of(walls: jax.Array) -> jax.Array:
    """bool[H, W]: free cells that are one-cell gaps in a straight wall (a wall on both sides along one axis,
    and neither neighbour across the gap walled in the same way, which a corridor's cells are); beyond the
    edge counts as wall."""
    free = ~walls
    flanked_across = _shift(walls, 0, -1, True) & _shift(walls, 0, 1, True)  # walls left and right
    flanked_down = _shift(walls, -1, 0, True) & _shift(walls, 1, 0, True)  # walls above and below
    gap_across = flanked_across & ~_shift(flanked_across & free, -1, 0, False) & ~_shift(flanked_across & free, 1, 0, False)
    gap_down = flanked_down & ~_shift(flanked_down & free, 0, -1, False) & ~_shift(flanked_down & free, 0, 1, False)
    return free & (gap_across | gap_down)


def rooms_from_walls(walls: jax.Array, num_rooms: int = NUM_ROOMS) -> jax.Array:
    """bool[R, H, W]: the ``num_rooms`` largest 4-connected areas of free cells once entrances are closed.

    A map of the generator's has at most ``NUM_ROOMS`` rooms; areas beyond the ``num_rooms`` largest
    (none on a generator layout) get no apples.
    """
    height, width = walls.shape
    cells = height * width
    inside = ~walls & ~entrances_of(walls)
    label = jnp.where(inside, jnp.arange(cells).reshape(height, width), -1)

    def spread(state):  # every free cell takes the largest label among itself and its 4 neighbours
        label, _ = state
        padded = jnp.pad(label, 1, constant_values=-1)
        shifted = [padded[1 + dr : 1 + dr + height, 1 + dc : 1 + dc + width] for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1))]
        grown = jnp.where(inside, functools.reduce(jnp.maximum, shifted, label), -1)
        return grown, (grown != label).any()

    label, _ = jax.lax.while_loop(lambda state: state[1], spread, (label, jnp.array(True)))
    sizes = jnp.zeros(cells + 1, jnp.int32).at[jnp.where(inside, label, cells).reshape(-1)].add(1)[:cells]
    largest = jax.lax.top_k(sizes, num_rooms)[1]
    kept = sizes[largest] > 0
    return (label[None] == largest[:, None, None]) & kept[:, None, None]
