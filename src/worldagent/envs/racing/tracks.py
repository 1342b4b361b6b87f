"""CarRacing's procedural track generator, batched, and the tracks as ``Track`` pytrees.

The paper (§5.2.1) builds its dataset of 10,000 racing worlds with Gymnasium CarRacing's track
generator (``CarRacing._create_track``). ``upstream_loops`` reimplements that generator
float for float: same random stream (``gymnasium.utils.seeding.np_random(seed)``, 24 uniform
draws per attempt), same walker, same loop cut, same rejection test, so ``upstream_loop(s)``
equals ``CarRacing().reset(seed=s)``'s ``env.unwrapped.track``. It runs all tracks of a batch
at once: one Python loop over walker iterations, numpy float64 over the batch (10,000 tracks
end to end, rasters included, in about 10 s on 2 CPU cores; upstream takes ~20 ms a track).

``generate_tracks`` turns the upstream loops into fixed-shape ``Track`` worlds: the loop is
resampled to ``NUM_POINTS`` points evenly by arc length, divided by ``PLAYFIELD`` (normalised
coordinates, see ``world.py``) and rasterised at ``RASTER_SIZE`` and ``ROAD_SIZE``.

Measured over seeds 0..9999 (``track_statistics``; mean ± std, [min, max]), kept in
``MEASURED_STATISTICS`` for the tests:

- upstream points per loop N: 292.2 ± 22.5, [218, 389]
- closed loop length: 1026 ± 79 upstream units, [769, 1365] (3.5 units per point)
- total absolute turning around the closed upstream polygon: 13.96 ± 2.53 rad, [6.5, 25.1]
  (more than 2π because the walker zigzags by up to 0.31 rad per step)
- max |coordinate| / PLAYFIELD: 0.685 ± 0.015, [0.676, 0.722] — always below the
  ``Track.validate`` bound ``MAX_EXTENT`` = 0.8; the start point (225, 0) gives the 0.675 floor.
- rejections: 6.3 % of attempts fail upstream's tests; 636 of 10,000 seeds need a retry
  (674 retries in all, at most 3 for one seed).
"""

from __future__ import annotations

import math

import numpy as np

from worldagent.envs.core import check_finite
from worldagent.envs.racing.world import (
    HALF_WIDTH,
    NUM_POINTS,
    PLAYFIELD,
    RASTER_SIZE,
    ROAD_SIZE,
    TRACK_DETAIL_STEP,
    TRACK_RAD,
    TRACK_TURN_RATE,
    UPSTREAM_SCALE,
    Track,
    pack_road,
    pixel_centres,
    to_pixel,
)
from worldagent.errors import WorldagentError

CHECKPOINTS = 12
MAX_ITERATIONS = 2500  # upstream's no_freeze
START_ALPHA = 2 * math.pi * (-0.5) / CHECKPOINTS  # upstream's self.start_alpha = -pi/12
_TWO_PI = 2 * math.pi
MEASURED_STATISTICS = {  # track_statistics over seeds 0..9999: (mean, std, min, max)
    "points": (292.17, 22.50, 218, 389),
    "length": (1026.1, 78.8, 769.0, 1365.0),
    "turning": (13.96, 2.53, 6.52, 25.09),
    "max_coord": (0.6846, 0.0147, 0.6759, 0.7219),
}
_FILL_CHUNK = 256  # tracks filled at once
_CHUNK = 2048  # tracks walked at once (bounds the f64[2500, 4, chunk] history to ~160 MB)


def seeds_from(seed: int, n: int) -> np.ndarray:
    """The CarRacing seeds of ``n`` tracks: track ``i`` uses seed ``seed + i``.

    Args:
        seed: the first seed, a non-negative integer.
        n: how many tracks, a positive integer.

    Returns:
        int64[n] seeds ``seed + arange(n)``.
    """
    for name, value in (("seed", seed), ("n", n)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise WorldagentError(f"{name}={value!r} is not an integer; pass a whole number.")
    if seed < 0:
        raise WorldagentError(f"seed={seed} is negative; pass a seed >= 0 (CarRacing seeds are non-negative).")
    if n <= 0:
        raise WorldagentError(f"n={n} tracks requested; pass a count of at least 1.")
    return int(seed) + np.arange(int(n), dtype=np.int64)


def _check_seeds(seeds) -> np.ndarray:
    """Validate a 1-d batch of non-negative integer seeds; returns int64[B]."""
    array = np.asarray(seeds)
    if array.ndim == 0:
        array = array[None]
    if array.ndim != 1 or array.size == 0:
        raise WorldagentError(f"seeds have shape {array.shape}; pass a non-empty 1-d list of integers (see seeds_from).")
    if array.dtype.kind not in "iu":
        raise WorldagentError(f"seeds have dtype {array.dtype}; pass integers (see seeds_from).")
    if array.min() < 0:
        raise WorldagentError(f"seed {int(array.min())} is negative; pass seeds >= 0 (see seeds_from).")
    return array.astype(np.int64)


def _draw_checkpoints(rngs: list[np.random.Generator]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Upstream's 12 checkpoints per generator: (alpha, x, y), each f64[B, 12]; 24 draws each."""
    low = np.array([0.0, TRACK_RAD / 3])
    high = np.array([2 * math.pi * 1 / CHECKPOINTS, TRACK_RAD])
    draws = np.stack([rng.uniform(low, high, size=(CHECKPOINTS, 2)) for rng in rngs])  # (noise, rad) in call order
    c = np.arange(CHECKPOINTS, dtype=np.float64)
    alpha = 2 * math.pi * c / CHECKPOINTS + draws[..., 0]
    rad = draws[..., 1].copy()
    alpha[:, 0], rad[:, 0] = 0.0, 1.5 * TRACK_RAD
    alpha[:, -1], rad[:, -1] = 2 * math.pi * (CHECKPOINTS - 1) / CHECKPOINTS, 1.5 * TRACK_RAD
    return alpha, rad * np.cos(alpha), rad * np.sin(alpha)


def _walk(cp_alpha: np.ndarray, cp_x: np.ndarray, cp_y: np.ndarray, buffer: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Upstream's walker for B tracks at once: history f64[T, 4, B] (alpha, beta, x, y) and lengths int[B]."""
    batch = cp_alpha.shape[0]
    history = buffer[: MAX_ITERATIONS * 4 * batch].reshape(MAX_ITERATIONS, 4, batch)  # reused: no page faults
    x = np.full(batch, 1.5 * TRACK_RAD)
    y = np.zeros(batch)
    beta = np.zeros(batch)
    dest_i = np.zeros(batch, dtype=np.int64)
    dest_alpha, dest_x, dest_y = cp_alpha[:, 0].copy(), cp_x[:, 0].copy(), cp_y[:, 0].copy()
    laps = np.zeros(batch, dtype=np.int64)
    visited = np.zeros(batch, dtype=bool)
    length = np.zeros(batch, dtype=np.int64)  # 0 while still walking
    proj, turn, step = np.empty(batch), np.empty(batch), np.empty(batch)
    # Finished tracks keep walking (their values past `length` are never read): no masks needed.
    for t in range(MAX_ITERATIONS):
        alpha, mid = history[t, 0], history[t, 1]
        np.arctan2(y, x, out=alpha)
        lap = visited & (alpha > 0)
        negative = alpha < 0
        visited = (visited & ~lap) | negative
        np.add(alpha, _TWO_PI, out=alpha, where=negative)
        if lap.any():
            laps += lap
            finished = (length == 0) & (laps > 4)
            length[finished] = t + 1
        failed = np.flatnonzero(alpha > dest_alpha)
        while failed.size:  # next checkpoint; alpha -= 2 pi when the search wraps (upstream's inner loops)
            dest_i[failed] += 1
            dest = dest_i[failed] % CHECKPOINTS
            alpha[failed] = np.where(dest == 0, alpha[failed] - _TWO_PI, alpha[failed])
            dest_alpha[failed], dest_x[failed], dest_y[failed] = (c[failed, dest] for c in (cp_alpha, cp_x, cp_y))
            failed = failed[alpha[failed] > dest_alpha[failed]]
        r1x, r1y = np.cos(beta), np.sin(beta)
        np.subtract(dest_x, x, out=proj)
        proj *= r1x
        np.subtract(dest_y, y, out=step)
        step *= r1y
        proj += step
        np.subtract(beta, alpha, out=step)
        if step.max() > 1.5 * math.pi or step.min() < -1.5 * math.pi:
            while (above := beta - alpha > 1.5 * math.pi).any():
                beta = np.where(above, beta - _TWO_PI, beta)
            while (below := beta - alpha < -1.5 * math.pi).any():
                beta = np.where(below, beta + _TWO_PI, beta)
        np.multiply(beta, 0.5, out=mid)  # prev_beta * 0.5 (+ new beta * 0.5 below)
        proj *= UPSTREAM_SCALE
        np.multiply(proj, 0.001, out=turn)
        np.abs(turn, out=turn)
        np.minimum(turn, TRACK_TURN_RATE, out=turn)
        beta = beta - np.where(proj > 0.3, turn, 0.0) + np.where(proj < -0.3, turn, 0.0)
        np.multiply(beta, 0.5, out=step)
        mid += step
        r1y *= TRACK_DETAIL_STEP
        x -= r1y  # x += (-sin beta) * step, bit for bit
        r1x *= TRACK_DETAIL_STEP
        y += r1x
        history[t, 2], history[t, 3] = x, y
        if t + 1 == MAX_ITERATIONS:
            length[length == 0] = MAX_ITERATIONS
        if t % 16 == 0 and (length > 0).all():
            return history[: t + 1], length
    return history, length


def _exact_alpha(loop: np.ndarray, before: np.ndarray) -> np.ndarray:
    """Recompute a loop's alpha column with libm's atan2 (numpy's may differ by 1 ulp); f64[N]."""
    raw = _atan2(before[:, 1], before[:, 0]).astype(np.float64)
    base = np.where(raw < 0, raw + _TWO_PI, raw)
    return np.where(loop[:, 0] < base - math.pi, base - _TWO_PI, base)


_atan2 = np.frompyfunc(math.atan2, 2, 1)


def _cut(history: np.ndarray, length: np.ndarray) -> list[np.ndarray | None]:
    """Upstream's cut between the last two start-line crossings and its glue test; None = rejected."""
    alpha = history[:, 0, :]  # [T, B]
    steps = np.arange(1, alpha.shape[0])[:, None]
    crossing = (alpha[1:] > START_ALPHA) & (alpha[:-1] <= START_ALPHA) & (steps < length[None, :])
    loops: list[np.ndarray | None] = []
    for b in range(alpha.shape[1]):
        found = np.flatnonzero(crossing[:, b]) + 1
        if found.size < 2:
            loops.append(None)
            continue
        i1, i2 = found[-2], found[-1]
        loop = np.ascontiguousarray(history[i1 : i2 - 1, :, b])
        first_beta = loop[0, 1]
        glue = np.sqrt(np.square(math.cos(first_beta) * (loop[0, 2] - loop[-1, 2])) + np.square(math.sin(first_beta) * (loop[0, 3] - loop[-1, 3])))
        if glue > TRACK_DETAIL_STEP:
            loops.append(None)
            continue
        loop[:, 0] = _exact_alpha(loop, history[i1 - 1 : i2 - 2, 2:, b])
        loops.append(loop)
    return loops


def upstream_loops(seeds, *, return_retries: bool = False):
    """Upstream CarRacing's tracks for a batch of seeds, computed vectorised over the batch.

    Implements ``CarRacing._create_track`` as called by ``reset(seed=seed)`` (paper §5.2.1 /
    upstream CarRacing): a rejected attempt is redrawn from the same, continuing generator.
    Rounds: every pending seed is walked (in chunks of 2,048), the rejected ones again.

    Args:
        seeds: B non-negative integer seeds (see ``seeds_from``).
        return_retries: also return int[B], how many attempts of each seed were rejected.

    Returns:
        A list of B arrays f64[N_b, 4] (alpha, beta, x, y) in upstream units, each
        upstream's ``env.unwrapped.track`` for that seed (``(loops, retries)`` if asked).

    Fidelity: bit-identical to gymnasium 1.x CarRacing-v3 on seeds 0..2999 (checked with
    ``np.array_equal``). The walker's decisions use numpy's ``arctan2``, which on AVX-512 CPUs can
    differ from libm's by 1 ulp (a decision would flip only for an angle within 1 ulp of a
    threshold); the returned alpha column is recomputed with ``math.atan2`` as upstream does.
    """
    seeds = _check_seeds(seeds)
    rngs = [np.random.Generator(np.random.PCG64(np.random.SeedSequence(int(s)))) for s in seeds]
    loops: list[np.ndarray | None] = [None] * len(seeds)
    retries = np.zeros(len(seeds), dtype=np.int64)
    pending = np.arange(len(seeds))
    buffer = np.empty(MAX_ITERATIONS * 4 * min(_CHUNK, len(seeds)))
    while pending.size:
        rejected = []
        for start in range(0, pending.size, _CHUNK):
            index = pending[start : start + _CHUNK]
            history, length = _walk(*_draw_checkpoints([rngs[i] for i in index]), buffer)
            for i, loop in zip(index, _cut(history, length)):
                if loop is None:
                    rejected.append(i)
                else:
                    loops[i] = loop
        pending = np.asarray(rejected, dtype=np.int64)
        retries[pending] += 1
    return (loops, retries) if return_retries else loops


def upstream_loop(seed: int) -> np.ndarray:
    """f64[N, 4] (alpha, beta, x, y): upstream's ``env.unwrapped.track`` after ``reset(seed=seed)``."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise WorldagentError(f"seed={seed!r} is not an integer; pass a whole number >= 0.")
    return upstream_loops([seed])[0]


def resample_loop(points_xy, num_points: int) -> np.ndarray:
    """Resample a closed polyline evenly by arc length.

    Args:
        points_xy: f[N, 2] vertices in driving order; the loop closes from N-1 back to 0.
        num_points: how many points to return (>= 3).

    Returns:
        f64[num_points, 2]: point 0 is ``points_xy[0]``, then equal arc-length steps of
        ``length / num_points`` in the same driving order (the closing step included).
    """
    points = check_finite("loop points", points_xy)
    if points.ndim != 2 or points.shape[1] != 2 or points.shape[0] < 3:
        raise WorldagentError(f"loop points have shape {points.shape}; pass (N, 2) with N >= 3.")
    if isinstance(num_points, bool) or not isinstance(num_points, (int, np.integer)) or num_points < 3:
        raise WorldagentError(f"num_points={num_points!r}; pass an integer >= 3.")
    closed = np.concatenate([points, points[:1]])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    if arc[-1] <= 0:
        raise WorldagentError("loop has zero length; pass distinct points.")
    target = np.arange(num_points) * (arc[-1] / num_points)
    return np.stack([np.interp(target, arc, closed[:, 0]), np.interp(target, arc, closed[:, 1])], axis=1)


def rasterize(centrelines, size: int) -> np.ndarray:
    """On-road masks: a pixel is road iff its centre is within ``HALF_WIDTH`` of the closed loop.

    Exact (float64 point-to-segment distances, pixel centres from ``world.pixel_centres``):
    each segment stamps the distance test onto the small window of pixels that can be within
    ``HALF_WIDTH`` of it, so the cost is O(B·K) windows, not O(B·K·size²).

    Args:
        centrelines: f[B, K, 2] normalised loops (closing segment K-1 -> 0 included), or f[K, 2].
        size: raster side in pixels (row 0 at the top, y = +1; see ``world.py``).

    Returns:
        bool[B, size, size] (bool[size, size] for an unbatched input).
    """
    lines = check_finite("centrelines", centrelines)
    if lines.ndim == 2:
        return rasterize(lines[None], size)[0]
    if lines.ndim != 3 or lines.shape[2] != 2 or lines.shape[1] < 2:
        raise WorldagentError(f"centrelines have shape {lines.shape}; pass (B, K, 2) normalised points.")
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 1:
        raise WorldagentError(f"raster size={size!r}; pass a positive integer.")
    centres = pixel_centres(size)
    col_x, row_y = centres[0, :, 0], centres[:, 0, 1]
    batch, k = lines.shape[:2]
    out = np.zeros((batch, size, size), dtype=bool)
    hw2 = HALF_WIDTH**2
    reach = HALF_WIDTH * size / 2  # the half-width in pixels
    span = np.abs(to_pixel(np.roll(lines, -1, axis=1), size) - to_pixel(lines, size)).max()
    width = int(np.ceil(span + 2 * reach)) + 2  # window side: every pixel that can be on road
    offsets = np.arange(width)
    chunk = max(1, 2**22 // (k * width * width))
    for lo in range(0, batch, chunk):
        p0 = lines[lo : lo + chunk]
        d = np.roll(p0, -1, axis=1) - p0  # segment vectors [b, K, 2]
        q0, q1 = to_pixel(p0, size), to_pixel(p0 + d, size)  # (row, col)
        first = np.floor(np.minimum(q0, q1) - reach).astype(np.int64)  # window corner
        rows = np.clip(first[..., 0, None] + offsets, 0, size - 1)  # [b, K, W]
        cols = np.clip(first[..., 1, None] + offsets, 0, size - 1)
        dx = col_x[cols] - p0[..., 0, None]  # [b, K, W]
        dy = row_y[rows] - p0[..., 1, None]
        inv = 1.0 / np.maximum((d**2).sum(-1), 1e-300)[..., None]
        t = np.clip((dx * (d[..., 0, None] * inv))[..., None, :] + (dy * (d[..., 1, None] * inv))[..., :, None], 0.0, 1.0)
        ex = dx[..., None, :] - t * d[..., 0, None, None]  # [b, K, W(rows), W(cols)]
        ey = dy[..., :, None] - t * d[..., 1, None, None]
        hit = ex * ex + ey * ey <= hw2
        flat = (np.arange(lo, lo + len(p0))[:, None, None, None] * size + rows[..., :, None]) * size + cols[..., None, :]
        out.reshape(-1)[flat[hit]] = True
    return out


def fill_interior(centrelines, size: int) -> np.ndarray:
    """Pixels whose centre lies inside the closed loop (even-odd rule), bool[B, size, size].

    Scanline parity, vectorised over the batch: for each pixel row, every loop edge that crosses
    the row's centre line (half-open in y, so a vertex is never counted twice) adds one to the
    first pixel column right of the crossing; a running sum along the row gives, for each pixel,
    the number of crossings to its left, and odd counts are inside.

    Args:
        centrelines: f[B, K, 2] normalised closed loops.
        size: raster side in pixels.
    """
    lines = np.asarray(centrelines, dtype=np.float64)
    if len(lines) > _FILL_CHUNK:  # bounded temporaries: f64[chunk, size, K]
        return np.concatenate([fill_interior(lines[i : i + _FILL_CHUNK], size) for i in range(0, len(lines), _FILL_CHUNK)])
    start, end = lines, np.roll(lines, -1, axis=1)
    row_y = pixel_centres(size)[:, 0, 1]  # [size]
    y0, y1 = start[:, None, :, 1], end[:, None, :, 1]  # [B, 1, K]
    crosses = (y0 > row_y[None, :, None]) != (y1 > row_y[None, :, None])  # [B, size, K]
    with np.errstate(divide="ignore", invalid="ignore"):
        x = start[:, None, :, 0] + (row_y[None, :, None] - y0) * (end[:, None, :, 0] - start[:, None, :, 0]) / (y1 - y0)
    first_right = np.clip(np.floor((x + 1.0) * size / 2.0 - 0.5) + 1, 0, size).astype(np.int64)  # x < centre of this col
    batch = len(lines)
    bins = (np.arange(batch)[:, None, None] * size + np.arange(size)[None, :, None]) * (size + 1) + first_right
    counts = np.bincount(bins[crosses], minlength=batch * size * (size + 1)).reshape(batch, size, size + 1)
    return (np.cumsum(counts[..., :size], axis=-1) % 2).astype(bool)


def footprint(centrelines, size: int) -> np.ndarray:
    """The track's footprint, bool[B, size, size]: its road and the area the road encloses.

    This is the VAE's input (``Track.raster``). A filled shape, unlike the 1–2 pixel wide road,
    overlaps a lot with the footprints of similar tracks, which is what lets the VAE learn a
    smooth latent space and the repair step find the most similar track (paper §5.2.1).
    """
    return rasterize(centrelines, size) | fill_interior(centrelines, size)


def generate_tracks(seeds, num_points: int = NUM_POINTS) -> Track:
    """A batch of CarRacing tracks as one ``Track`` of numpy arrays (paper §5.2.1).

    Args:
        seeds: B non-negative integer seeds; track ``i`` is CarRacing's track for ``seeds[i]``.
        num_points: K, centreline points per track.

    Returns:
        ``Track`` with centreline f32[B, K, 2] (the upstream loop resampled evenly by arc
        length, divided by ``PLAYFIELD``), raster bool[B, 64, 64] (the ``footprint``, the VAE's
        input) and road uint32[B, 128, 4]
        (the 128×128 on-road mask, bit-packed with ``world.pack_road``).
        The same seeds always give identical arrays.
    """
    if isinstance(num_points, bool) or not isinstance(num_points, (int, np.integer)) or num_points < 8:
        raise WorldagentError(f"num_points={num_points!r}; pass an integer >= 8.")
    loops = upstream_loops(seeds)
    centreline = np.stack([resample_loop(loop[:, 2:], num_points) for loop in loops]) / PLAYFIELD
    centreline = centreline.astype(np.float32)
    road = pack_road(rasterize(centreline, ROAD_SIZE))
    return Track(centreline=centreline, raster=footprint(centreline, RASTER_SIZE), road=road)


def generate_track(seed: int, num_points: int = NUM_POINTS) -> Track:
    """One CarRacing track (no batch axis): centreline f32[K, 2], raster bool[64, 64], road uint32[128, 4]."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise WorldagentError(f"seed={seed!r} is not an integer; pass a whole number >= 0.")
    batch = generate_tracks([seed], num_points)
    return Track(centreline=batch.centreline[0], raster=batch.raster[0], road=batch.road[0])


def track_statistics(seeds_or_loops) -> dict:
    """Per-track shape statistics of upstream loops, and their summary.

    Args:
        seeds_or_loops: integer seeds, or a list of upstream loops f[N, 4] (or f[N, 2] x, y).

    Returns:
        dict with per-track arrays ``points`` int[B] (upstream N), ``length`` f64[B] (closed
        loop length, upstream units), ``turning`` f64[B] (sum of absolute heading changes
        around the closed loop, rad), ``max_coord`` f64[B] (max |x|, |y| / PLAYFIELD), and
        ``summary``: {name: {"mean", "std", "min", "max"}} for each of them.
    """
    items = list(seeds_or_loops) if not isinstance(seeds_or_loops, np.ndarray) else seeds_or_loops
    if len(items) and np.ndim(items[0]) == 2:
        loops = [check_finite("loop", loop) for loop in items]
    else:
        loops = upstream_loops(items)
    stats: dict = {"points": [], "length": [], "turning": [], "max_coord": []}
    for loop in loops:
        xy = loop[:, -2:]
        step = np.diff(np.concatenate([xy, xy[:1]]), axis=0)
        heading = np.arctan2(step[:, 1], step[:, 0])
        change = np.angle(np.exp(1j * (np.roll(heading, -1) - heading)))
        stats["points"].append(len(loop))
        stats["length"].append(np.linalg.norm(step, axis=1).sum())
        stats["turning"].append(np.abs(change).sum())
        stats["max_coord"].append(np.abs(xy).max() / PLAYFIELD)
    stats = {name: np.asarray(values) for name, values in stats.items()}
    stats["summary"] = {
        name: {"mean": float(v.mean()), "std": float(v.std()), "min": float(v.min()), "max": float(v.max())} for name, v in stats.items()
    }
    return stats


__all__ = [
    "generate_track",
    "generate_tracks",
    "rasterize",
    "resample_loop",
    "seeds_from",
    "track_statistics",
    "upstream_loop",
    "upstream_loops",
]
