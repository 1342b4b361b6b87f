"""The racing world: a closed track as a fixed-shape pytree, and the one coordinate convention.

Coordinates. Upstream CarRacing works in "units" (its SCALE = 6 pixels per unit). We divide by
its playfield half-size, ``PLAYFIELD = 2000 / 6`` units, so a track lives in normalised
coordinates ``(x, y)`` in ``[-1, 1]²``, x to the right and y up. The track half-width is then
``HALF_WIDTH = (40 / 6) / PLAYFIELD = 0.02``.

Rasters. Every raster in the package, ``raster[row, col]``, has row 0 at the top (y = +1) and
column 0 at the left (x = -1), like an image: pixel ``(r, c)`` of an ``R×R`` raster has its
centre at ``x = -1 + (c + 0.5)·2/R``, ``y = 1 - (r + 0.5)·2/R``. ``to_pixel`` and
``pixel_centres`` are the only places that convert; use them.
"""

from __future__ import annotations

import jax
import numpy as np
from flax import struct

from worldagent.envs.core import check_finite
from worldagent.errors import WorldagentError

# Upstream CarRacing constants (gymnasium/envs/box2d/car_racing.py), in its units.
UPSTREAM_SCALE = 6.0
TRACK_RAD = 900 / UPSTREAM_SCALE  # 150
TRACK_DETAIL_STEP = 21 / UPSTREAM_SCALE  # 3.5
TRACK_TURN_RATE = 0.31
TRACK_WIDTH = 40 / UPSTREAM_SCALE  # the half-width, despite its name
PLAYFIELD = 2000 / UPSTREAM_SCALE

HALF_WIDTH = TRACK_WIDTH / PLAYFIELD  # 0.02 in normalised coordinates
NUM_POINTS = 256  # centreline points per track
RASTER_SIZE = 64  # the VAE's input (paper §5.2.1)
ROAD_SIZE = 128  # the env's on-road mask, from which observation windows are cut
ROAD_WORDS = ROAD_SIZE // 32  # the road mask is stored bit-packed: 32 pixels per uint32 word
# Tracks must stay inside |x|, |y| <= MAX_EXTENT so that the env's observation window (±0.125
# with a 16-pixel window, the paper's), the road's half-width and one step of overshoot stay on
# the road mask. CarRacing's tracks reach at most 0.722 (measured over seeds 0..9999).
MAX_EXTENT = 0.8


@struct.dataclass
class Track:
    """One track (or a batch, with a leading axis on every field).

    Attributes:
        centreline: f32[K, 2] normalised points of the closed loop, evenly spaced by arc length,
            in driving order (counter-clockwise, as upstream); point 0 is the start line and
            the loop closes from point K-1 back to point 0.
        raster: bool[64, 64] the track's footprint, the VAE's input (row 0 at the top): the road
            and the area it encloses (see ``tracks.footprint`` for why filled).
        road: uint32[128, 4] on-road pixels at the env's resolution, bit-packed (``pack_road``):
            bit k of ``road[r, j]`` is pixel ``(r, 32·j + k)``. Packing makes a world 8× smaller
            and lets the env cut its observation window as one contiguous 16-row read.
    """

    centreline: jax.Array
    raster: jax.Array
    road: jax.Array

    @property
    def num_points(self) -> int:
        return self.centreline.shape[-2]

    def validate(self) -> None:
        """Host-side check of shapes, finiteness, bounds and closure; raises ``WorldagentError``."""
        centreline = check_finite("track centreline", self.centreline)
        if centreline.ndim < 2 or centreline.shape[-1] != 2 or centreline.shape[-2] < 8:
            raise WorldagentError(f"track centreline has shape {centreline.shape}; expected (K, 2) with K >= 8 points.")
        batch = centreline.shape[:-2]
        for name, value, want in (
            ("raster", self.raster, (RASTER_SIZE, RASTER_SIZE)),
            ("road", self.road, (ROAD_SIZE, ROAD_WORDS)),
        ):
            if np.shape(value) != batch + want:
                raise WorldagentError(f"track {name} has shape {np.shape(value)}; expected {batch + want} (see generate_tracks).")
        if np.asarray(self.road).dtype != np.uint32:
            raise WorldagentError(f"track road has dtype {np.asarray(self.road).dtype}; pack the bool mask with pack_road().")
        if np.abs(centreline).max() > MAX_EXTENT:
            raise WorldagentError(
                f"track reaches {np.abs(centreline).max():.3f}, beyond the playable square |x|, |y| <= {MAX_EXTENT}; "
                "scale it down or generate it with generate_tracks()."
            )
        steps = np.linalg.norm(np.diff(centreline, axis=-2, append=centreline[..., :1, :]), axis=-1)
        if np.any(steps.max(axis=-1) > 4 * HALF_WIDTH):
            raise WorldagentError("track centreline is not a closed, evenly sampled loop; resample it with resample_loop().")


def pack_road(mask) -> np.ndarray:
    """bool[..., R, R] -> uint32[..., R, R/32]: bit k of word j of a row is column ``32·j + k``."""
    mask = np.asarray(mask, dtype=bool)
    if mask.shape[-1] % 32:
        raise WorldagentError(f"road mask has {mask.shape[-1]} columns; pack_road needs a multiple of 32.")
    packed = np.packbits(mask, axis=-1, bitorder="little")  # bit k of byte b is column 8b + k
    return np.ascontiguousarray(packed).view("<u4").astype(np.uint32)


def unpack_road(packed) -> np.ndarray:
    """uint32[..., R, W] -> bool[..., R, 32·W], the inverse of ``pack_road``."""
    packed = np.asarray(packed, dtype=np.uint32)
    bits = (packed[..., None] >> np.arange(32, dtype=np.uint32)) & 1
    return bits.reshape(*packed.shape[:-1], packed.shape[-1] * 32).astype(bool)


def to_pixel(xy: np.ndarray, size: int) -> np.ndarray:
    """Normalised ``[..., 2]`` (x, y) -> continuous ``[..., 2]`` (row, col) in an ``size×size`` raster."""
    xy = np.asarray(xy)
    col = (xy[..., 0] + 1.0) * size / 2.0 - 0.5
    row = (1.0 - xy[..., 1]) * size / 2.0 - 0.5
    return np.stack([row, col], axis=-1)


def pixel_centres(size: int) -> np.ndarray:
    """f64[size, size, 2]: the normalised (x, y) of each pixel centre of a ``size×size`` raster."""
    centres = -1.0 + (np.arange(size) + 0.5) * 2.0 / size
    x = np.broadcast_to(centres[None, :], (size, size))
    y = np.broadcast_to(centres[::-1, None], (size, size))
    return np.stack([x, y], axis=-1)
