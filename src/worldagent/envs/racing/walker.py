"""CarRacing's track walker in JAX: any set of checkpoints -> a ``Track``, inside jitted code.

``tracks.py`` replays upstream's generator float for float in numpy, for the dataset. The open
repair (``open_repair.py``) needs the same construction for checkpoints it reads off decoded
latents, batched and inside jitted training programs, so this module is that walker again as a
pure JAX function of a batch of checkpoint sets:

1. ``walk``: upstream's walker (steer towards the next checkpoint, turning at most
   ``TRACK_TURN_RATE`` per ``TRACK_DETAIL_STEP``) for up to 2,500 steps or five laps, keeping the
   last ``RING`` steps and the last two start-line crossings, every track of the batch in lockstep;
2. ``cut``: upstream's loop between those two crossings and its rejection test (two crossings,
   glued within one step);
3. ``resample``: the loop evenly by arc length, ``NUM_POINTS`` points, normalised (as
   ``tracks.resample_loop``);
4. ``road_mask`` / ``interior_mask``: the road and footprint rasters (as ``tracks.rasterize`` and
   ``tracks.fill_interior``), stamped per segment so a track costs O(K) pixels, not O(K·R²).

It runs in float32: a track differs from upstream's float64 one by rounding, not in shape (the
walker converges to the same closed loop; ``tests/envs/racing/test_walker.py`` measures it).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.envs.racing.tracks import CHECKPOINTS, MAX_ITERATIONS, START_ALPHA  # upstream's, one place
from worldagent.envs.racing.world import (
    HALF_WIDTH,
    MAX_EXTENT,
    NUM_POINTS,
    PLAYFIELD,
    RASTER_SIZE,
    ROAD_SIZE,
    TRACK_DETAIL_STEP,
    TRACK_RAD,
    TRACK_TURN_RATE,
    UPSTREAM_SCALE,
    Track,
    pixel_centres,
)

RING = 1024  # steps kept: a lap is 218-389 steps on the dataset, at most ~700 for any checkpoint set in the box
TWO_PI = 2 * math.pi
RAD_RANGE = (TRACK_RAD / 3, TRACK_RAD)  # upstream's draw of a free checkpoint's radius
NOISE_RANGE = (0.0, TWO_PI / CHECKPOINTS)  # and of its angle within its sector
FREE = CHECKPOINTS - 2  # checkpoints 0 and 11 are fixed by upstream (angle 0 and 330 degrees, radius 1.5 R)


class Walk(NamedTuple):
    """The walker's last ``RING`` steps and where each track's loop lies (B tracks).

    Attributes:
        ring: f32[RING, 3, B] (mean heading beta, x, y) of step t at row ``t % RING``.
        length: i32[B] steps walked.
        first, last: i32[B] the last two start-line crossings (-1: fewer crossings).
    """

    ring: jax.Array
    length: jax.Array
    first: jax.Array
    last: jax.Array


def checkpoints(noise: jax.Array, rad: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Upstream's 12 checkpoints (alpha, x, y), each f32[..., 12], from the free ones' draws.

    Args:
        noise: f32[..., 10] angle of checkpoints 1..10 within their 30-degree sector, radians in ``NOISE_RANGE``.
        rad: f32[..., 10] their radius, upstream units in ``RAD_RANGE``.
    """
    batch = noise.shape[:-1]
    c = jnp.arange(1, CHECKPOINTS - 1, dtype=jnp.float32)
    alpha = jnp.concatenate(
        [jnp.zeros((*batch, 1)), TWO_PI * c / CHECKPOINTS + noise, jnp.full((*batch, 1), TWO_PI * (CHECKPOINTS - 1) / CHECKPOINTS)], axis=-1
    )
    radius = jnp.concatenate([jnp.full((*batch, 1), 1.5 * TRACK_RAD), rad, jnp.full((*batch, 1), 1.5 * TRACK_RAD)], axis=-1)
    return alpha.astype(jnp.float32), (radius * jnp.cos(alpha)).astype(jnp.float32), (radius * jnp.sin(alpha)).astype(jnp.float32)


def _destination(alpha, dest_i, cp_alpha):
    """Upstream's search for the next checkpoint, [B] each: (alpha, possibly less 2 pi; dest_i; checkpoint index)."""
    k = dest_i % CHECKPOINTS
    ahead = (jnp.arange(CHECKPOINTS) >= k[:, None]) & (alpha[:, None] <= cp_alpha)
    found = ahead.any(axis=1)
    index = jnp.where(found, jnp.argmax(ahead, axis=1), 0)
    dest_i = jnp.where(found, dest_i + index - k, dest_i + CHECKPOINTS - k)
    return jnp.where(found, alpha, alpha - TWO_PI), dest_i, index


def _wrap_towards(beta, alpha):
    """beta shifted by whole turns until |beta - alpha| <= 1.5 pi (upstream's two while loops)."""
    above = jnp.maximum(jnp.ceil((beta - alpha - 1.5 * math.pi) / TWO_PI), 0.0)
    below = jnp.maximum(jnp.ceil((alpha - beta - 1.5 * math.pi) / TWO_PI), 0.0)
    return beta - TWO_PI * above + TWO_PI * below


def walk(cp_alpha: jax.Array, cp_x: jax.Array, cp_y: jax.Array) -> Walk:
    """Upstream's walker over B checkpoint sets f32[B, 12] each (``tracks._walk`` in JAX).

    All tracks step in lockstep, so the ring row written at step t is one scalar for the batch (an
    in-place write), and the loop runs a fixed ``MAX_ITERATIONS`` steps, a finished track standing
    still: a loop whose length depended on the data would, under an outer ``vmap``, turn every write
    into a copy of the ring.
    """
    batch = cp_alpha.shape[0]
    rows = jnp.arange(batch)

    def step(t, carry):
        x, y, beta, dest_i, laps, visited, prev_alpha, first, last, length, ring = carry
        walking = length == 0
        alpha = jnp.arctan2(y, x)
        lap = visited & (alpha > 0)
        laps = laps + lap
        visited = (visited & ~lap) | (alpha < 0)
        alpha = jnp.where(alpha < 0, alpha + TWO_PI, alpha)
        alpha, dest_i, index = _destination(alpha, dest_i, cp_alpha)
        r1x, r1y = jnp.cos(beta), jnp.sin(beta)
        proj = (r1x * (cp_x[rows, index] - x) + r1y * (cp_y[rows, index] - y)) * UPSTREAM_SCALE
        beta = _wrap_towards(beta, alpha)
        turn = jnp.minimum(TRACK_TURN_RATE, jnp.abs(0.001 * proj))
        new_beta = beta - jnp.where(proj > 0.3, turn, 0.0) + jnp.where(proj < -0.3, turn, 0.0)
        x, y = jnp.where(walking, x - r1y * TRACK_DETAIL_STEP, x), jnp.where(walking, y + r1x * TRACK_DETAIL_STEP, y)
        crossing = walking & (t > 0) & (alpha > START_ALPHA) & (prev_alpha <= START_ALPHA)
        first, last = jnp.where(crossing, last, first), jnp.where(crossing, t, last)
        length = jnp.where(walking & ((laps > 4) | (t + 1 == MAX_ITERATIONS)), t + 1, length)
        written = jnp.stack([0.5 * beta + 0.5 * new_beta, x, y])[None]
        ring = jax.lax.dynamic_update_slice(ring, jnp.where(walking, written, ring[t % RING][None]), (t % RING, 0, 0))
        return x, y, new_beta, dest_i, laps, visited, alpha, first, last, length, ring

    f32, i32 = jnp.float32, jnp.int32
    full = lambda value, dtype: jnp.full(batch, value, dtype)  # noqa: E731
    start = (full(1.5 * TRACK_RAD, f32), full(0.0, f32), full(0.0, f32), full(0, i32), full(0, i32), full(False, bool), full(0.0, f32))
    start = (*start, full(-1, i32), full(-1, i32), full(0, i32), jnp.zeros((RING, 3, batch), f32))
    carry = jax.lax.fori_loop(0, MAX_ITERATIONS, step, start)
    return Walk(carry[-1], carry[-2], carry[-4], carry[-3])


def cut(walked: Walk) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Upstream's loops ``[first, last - 1)`` and their acceptance: (xy f32[B, RING, 2], points i32[B], accepted bool[B]).

    Row k of ``xy[b]`` is step ``first + k`` (rows from ``points`` on are padding). Rejected, as upstream
    rejects: fewer than two crossings, or head and tail not glued within one step; also a loop
    that no longer fits the ring.
    """
    first, last = walked.first, walked.last
    points = last - 1 - first
    ring = jnp.moveaxis(walked.ring, -1, 0)  # [B, RING, 3]
    rows = (first[:, None] + jnp.arange(RING)) % RING
    loop = jnp.take_along_axis(ring, rows[..., None], axis=1)
    head, tail = loop[:, 0], jnp.take_along_axis(ring, ((last - 2) % RING)[:, None, None], axis=1)[:, 0]
    glue = jnp.hypot(jnp.cos(head[:, 0]) * (head[:, 1] - tail[:, 1]), jnp.sin(head[:, 0]) * (head[:, 2] - tail[:, 2]))
    fits = walked.length - first <= RING
    accepted = (first >= 1) & (points >= 3) & fits & (glue <= TRACK_DETAIL_STEP)
    return loop[..., 1:], points, accepted


def resample(xy: jax.Array, points: jax.Array, num_points: int = NUM_POINTS) -> jax.Array:
    """f32[num_points, 2]: the closed loop of the first ``points`` rows of ``xy`` f32[RING, 2], evenly
    by arc length from row 0, divided by ``PLAYFIELD`` (``tracks.resample_loop`` in JAX)."""
    index = jnp.arange(len(xy))
    following = jnp.where(index + 1 < points, index + 1, 0)
    segment = jnp.where(index < points, jnp.linalg.norm(xy[following] - xy, axis=1), 0.0)
    arc = jnp.cumsum(segment)
    start = arc - segment  # arc length at each row
    target = jnp.arange(num_points) * (arc[-1] / num_points)
    row = jnp.clip(jnp.searchsorted(arc, target, side="right"), 0, len(xy) - 1)
    fraction = jnp.where(segment[row] > 0, (target - start[row]) / jnp.maximum(segment[row], 1e-12), 0.0)
    out = xy[row] + fraction[:, None] * (xy[following[row]] - xy[row])
    return (out / PLAYFIELD).astype(jnp.float32)


def _window(size: int, longest: float) -> int:
    """Side of the pixel window that holds every pixel within ``HALF_WIDTH`` of a segment up to ``longest`` long."""
    reach = HALF_WIDTH * size / 2
    return int(math.ceil(longest * size / 2 + 2 * reach)) + 2


def road_mask(centreline: jax.Array, size: int) -> jax.Array:
    """bool[size, size]: pixels whose centre is within ``HALF_WIDTH`` of the closed loop f32[K, 2]."""
    centres = jnp.asarray(pixel_centres(size), jnp.float32)
    start, vector = centreline, jnp.roll(centreline, -1, axis=0) - centreline
    width = _window(size, 4 * HALF_WIDTH)  # Track.validate bounds a segment by 4 half-widths
    corner_col = jnp.floor((jnp.minimum(start[:, 0], start[:, 0] + vector[:, 0]) + 1.0) * size / 2 - 0.5 - HALF_WIDTH * size / 2).astype(jnp.int32)
    corner_row = jnp.floor((1.0 - jnp.maximum(start[:, 1], start[:, 1] + vector[:, 1])) * size / 2 - 0.5 - HALF_WIDTH * size / 2).astype(jnp.int32)
    offsets = jnp.arange(width)
    rows = jnp.clip(corner_row[:, None, None] + offsets[None, :, None], 0, size - 1)  # [K, W, 1]
    cols = jnp.clip(corner_col[:, None, None] + offsets[None, None, :], 0, size - 1)  # [K, 1, W]
    px, py = centres[0, cols, 0], centres[rows, 0, 1]
    dx, dy = px - start[:, None, None, 0], py - start[:, None, None, 1]
    vx, vy = vector[:, None, None, 0], vector[:, None, None, 1]
    t = jnp.clip((dx * vx + dy * vy) / jnp.maximum(vx * vx + vy * vy, 1e-12), 0.0, 1.0)
    hit = (dx - t * vx) ** 2 + (dy - t * vy) ** 2 <= HALF_WIDTH**2
    flat = jnp.broadcast_to(rows * size + cols, hit.shape)
    return jnp.zeros(size * size, bool).at[flat.reshape(-1)].max(hit.reshape(-1)).reshape(size, size)


def interior_mask(centreline: jax.Array, size: int) -> jax.Array:
    """bool[size, size]: pixels whose centre lies inside the closed loop (even-odd scanlines, as ``tracks.fill_interior``)."""
    row_y = jnp.asarray(pixel_centres(size)[:, 0, 1], jnp.float32)
    start, end = centreline, jnp.roll(centreline, -1, axis=0)
    y0, y1 = start[None, :, 1], end[None, :, 1]
    crosses = (y0 > row_y[:, None]) != (y1 > row_y[:, None])  # [size, K]
    x = start[None, :, 0] + (row_y[:, None] - y0) * (end[None, :, 0] - start[None, :, 0]) / jnp.where(crosses, y1 - y0, 1.0)
    first_right = jnp.clip(jnp.floor((x + 1.0) * size / 2.0 - 0.5) + 1, 0, size).astype(jnp.int32)
    counts = jnp.zeros((size, size + 1), jnp.int32).at[jnp.arange(size)[:, None], first_right].add(crosses.astype(jnp.int32))
    return (jnp.cumsum(counts[:, :size], axis=1) % 2).astype(bool)


def pack_bits(mask: jax.Array) -> jax.Array:
    """bool[R, R] -> uint32[R, R/32], bit k of word j being column 32·j + k (``world.pack_road`` in JAX)."""
    bits = mask.reshape(mask.shape[0], -1, 32).astype(jnp.uint32)
    return (bits << jnp.arange(32, dtype=jnp.uint32)).sum(axis=-1, dtype=jnp.uint32)


def track_from_centreline(centreline: jax.Array) -> Track:
    """The ``Track`` of a normalised closed centreline f32[K, 2]: its footprint and packed road rasters."""
    footprint = road_mask(centreline, RASTER_SIZE) | interior_mask(centreline, RASTER_SIZE)
    return Track(centreline=centreline, raster=footprint, road=pack_bits(road_mask(centreline, ROAD_SIZE)))


def build(noise: jax.Array, rad: jax.Array, num_points: int = NUM_POINTS) -> tuple[jax.Array, jax.Array]:
    """(centrelines f32[B, num_points, 2], accepted bool[B]) of the tracks upstream's walker draws
    through the checkpoints with free draws ``noise``, ``rad`` f32[B, 10] each; accepted as upstream
    accepts and inside the playable square."""
    xy, points, accepted = cut(walk(*checkpoints(noise, rad)))
    centreline = jax.vmap(lambda line, count: resample(line, count, num_points))(xy, points)
    return centreline, accepted & (jnp.abs(centreline).max(axis=(1, 2)) <= MAX_EXTENT)


def draws(rngs: list[np.random.Generator]) -> tuple[np.ndarray, np.ndarray]:
    """(noise, rad) f64[B, 10] of upstream's next 24 draws for each generator (``tracks._draw_checkpoints``)."""
    low, high = np.array([NOISE_RANGE[0], RAD_RANGE[0]]), np.array([NOISE_RANGE[1], RAD_RANGE[1]])
    values = np.stack([rng.uniform(low, high, size=(CHECKPOINTS, 2)) for rng in rngs])
    return values[:, 1:-1, 0], values[:, 1:-1, 1]
