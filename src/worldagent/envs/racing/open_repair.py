"""Racing's open repair: decoded footprint logits -> CarRacing checkpoints -> a new valid track.

The paper's repair (``envs.repairs.NearestWorld``) maps a decoded footprint to the most similar
of the 10,000 dataset tracks, so G(z) can only ever return a dataset track and searching z is
searching a fixed list. This repair decodes into the procedural generator's own terms instead
and builds the track from them with its own walker (``walker.py``), so every track it returns is
one CarRacing's generator could draw, valid by construction, yet almost never a dataset track:

1. ``profile``: the decoded footprint's radius along ``ANGLES`` rays from the centre (the filled
   length of each ray, so a blurry decode still gives a radius);
2. ``checkpoint draws``: the 20 numbers upstream draws for its 10 free checkpoints (an angle
   within each 30-degree sector and a radius), read off the profile by a linear map fitted once
   by least squares on CarRacing's own tracks (``fit_inverse``; shipped in ``INVERSE_FILE``) and
   clipped to upstream's ranges;
3. the walker's track through them; a set the walker rejects (6 % of upstream's own draws) is
   projected towards the centre of the ranges, step by step, until the walker accepts it.

On CarRacing tracks the map rebuilds the track it was shown with footprint IoU 0.93 (median),
0.89 (10th percentile) (``tests/envs/racing/test_open_tracks.py``). Decoding is pure JAX, so G(z)
stays usable inside jitted training programs; its cost is measured by ``benchmarks/open_worlds.py``.
"""

from __future__ import annotations

from importlib import resources

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jax.scipy.ndimage import map_coordinates

from worldagent.envs.racing import walker
from worldagent.envs.racing.world import MAX_EXTENT, RASTER_SIZE, Track
from worldagent.errors import WorldagentError

ANGLES = 120  # rays of the footprint profile (3 degrees apart; a checkpoint's sector spans 10)
RAY_SAMPLES = 96  # samples along each ray, out to MAX_EXTENT
SHRINK = (0.0, 0.1, 0.25, 0.5, 1.0)  # projection steps towards the centre of the ranges; the centre itself is accepted
INVERSE_FILE = "open_inverse.npz"
RIDGE = 0.1  # least-squares penalty of fit_inverse (0.001 to 1 give the same tracks to within 1 % IoU)


def profile(probabilities: jax.Array) -> jax.Array:
    """f32[ANGLES]: the footprint's filled length along each ray from the centre, normalised units.

    Args:
        probabilities: f32[64, 64] footprint probabilities (row 0 at the top, as every raster).
    """
    angle = jnp.arange(ANGLES) * (2 * jnp.pi / ANGLES)
    radius = (jnp.arange(RAY_SAMPLES) + 0.5) * (MAX_EXTENT / RAY_SAMPLES)
    x, y = radius[None, :] * jnp.cos(angle)[:, None], radius[None, :] * jnp.sin(angle)[:, None]
    col, row = (x + 1.0) * RASTER_SIZE / 2 - 0.5, (1.0 - y) * RASTER_SIZE / 2 - 0.5
    values = map_coordinates(probabilities, [row.reshape(-1), col.reshape(-1)], order=1, mode="constant")
    return values.reshape(ANGLES, RAY_SAMPLES).sum(axis=1) * (MAX_EXTENT / RAY_SAMPLES)


def to_unit(noise, rad):
    """Checkpoint draws f[..., 10] each -> f[..., 20] in [0, 1]^20 (upstream's ranges scaled)."""
    return jnp.concatenate([(noise - walker.NOISE_RANGE[0]) / (walker.NOISE_RANGE[1] - walker.NOISE_RANGE[0]),
                            (rad - walker.RAD_RANGE[0]) / (walker.RAD_RANGE[1] - walker.RAD_RANGE[0])], axis=-1)  # fmt: skip


def from_unit(unit):
    """f[..., 20] in [0, 1] -> (noise, rad) f[..., 10] each, inverse of ``to_unit``."""
    noise = walker.NOISE_RANGE[0] + unit[..., : walker.FREE] * (walker.NOISE_RANGE[1] - walker.NOISE_RANGE[0])
    return noise, walker.RAD_RANGE[0] + unit[..., walker.FREE :] * (walker.RAD_RANGE[1] - walker.RAD_RANGE[0])


def _features(profiles: jax.Array) -> jax.Array:
    """f32[..., ANGLES + 1]: the profile and a constant."""
    return jnp.concatenate([profiles, jnp.ones((*profiles.shape[:-1], 1), profiles.dtype)], axis=-1)


def project(unit: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(centrelines f32[B, K, 2], the draws used f32[B, 20], accepted bool[B]) for draws ``unit`` f32[B, 20]
    in [0, 1]: the walker's tracks, and where it rejects a set, the track of the first of ``SHRINK``'s
    steps towards the centre of the ranges that it accepts (one more walk of the batch per step taken)."""
    steps = jnp.asarray(SHRINK, jnp.float32)

    def attempt(carry):
        stage, accepted, used, lines = carry
        shrunk = 0.5 + (1.0 - steps[stage + 1]) * (unit - 0.5)
        new_lines, ok = walker.build(*from_unit(shrunk))
        redo = ~accepted
        return stage + 1, accepted | ok, jnp.where(redo[:, None], shrunk, used), jnp.where(redo[:, None, None], new_lines, lines)

    def rejected(carry):
        return ~carry[1].all() & (carry[0] < len(SHRINK) - 1)

    lines, accepted = walker.build(*from_unit(unit))
    _, accepted, used, lines = jax.lax.while_loop(rejected, attempt, (jnp.int32(0), accepted, unit, lines))
    return lines, used, accepted


@struct.dataclass
class OpenTracks:
    """New valid tracks built by CarRacing's walker from checkpoints read off the decoded footprint.

    Attributes:
        inverse: f32[ANGLES + 1, 20] the fitted map from a footprint profile to checkpoint draws in [0, 1].
    """

    inverse: jax.Array

    @classmethod
    def from_dataset(cls, dataset, config=None) -> OpenTracks:
        """The repair (it reads no dataset world: every track it returns is built, not looked up); no settings."""
        del dataset
        if config:
            raise WorldagentError(f"racing's open repair has no settings (given: {', '.join(config)}); drop them from --repair.")
        return cls(jnp.asarray(load_inverse()))

    @property
    def config(self) -> dict:
        return {}

    def draws(self, logits: jax.Array) -> jax.Array:
        """f32[B, 20]: checkpoint draws in [0, 1] read off footprint logits f32[B, 4096] (before projection)."""
        probabilities = jax.nn.sigmoid(logits.astype(jnp.float32)).reshape(-1, RASTER_SIZE, RASTER_SIZE)
        return jnp.clip(_features(jax.vmap(profile)(probabilities)) @ self.inverse, 0.0, 1.0)

    def __call__(self, logits: jax.Array) -> Track:
        """Valid tracks for decoded footprint logits f32[B, 4096] (batched, jittable)."""
        lines, _, _ = project(self.draws(logits))
        return jax.vmap(walker.track_from_centreline)(lines)


def load_inverse() -> np.ndarray:
    """f32[ANGLES + 1, 20]: the shipped least-squares map (``fit_inverse``)."""
    with resources.files("worldagent.envs.racing").joinpath(INVERSE_FILE).open("rb") as handle:
        return np.load(handle, allow_pickle=False)["inverse"].astype(np.float32)


def fit_inverse(seeds, chunk: int = 1000) -> tuple[np.ndarray, dict]:
    """Fit the profile -> checkpoint-draws map by ridge regression on CarRacing's tracks.

    Each seed's first 24 draws are its checkpoints; seeds whose first set the walker rejects
    (upstream redraws those) are left out. Returns (inverse f32[ANGLES + 1, 20], {"tracks": used}).
    """
    features, targets = [], []
    build = jax.jit(walker.build)
    describe = jax.jit(jax.vmap(lambda line: profile(walker.track_from_centreline(line).raster.astype(jnp.float32))))
    for start in range(0, len(seeds), chunk):
        rngs = [np.random.Generator(np.random.PCG64(np.random.SeedSequence(int(s)))) for s in seeds[start : start + chunk]]
        noise, rad = (jnp.asarray(a, jnp.float32) for a in walker.draws(rngs))
        lines, ok = build(noise, rad)
        ok = np.asarray(ok)
        features.append(np.asarray(_features(describe(lines)))[ok])
        targets.append(np.asarray(to_unit(noise, rad))[ok])
    x, y = np.concatenate(features).astype(np.float64), np.concatenate(targets).astype(np.float64)
    inverse = np.linalg.solve(x.T @ x + RIDGE * np.eye(x.shape[1]), x.T @ y)
    return inverse.astype(np.float32), {"tracks": int(len(x))}


FIT_SEEDS = 8000  # CarRacing seeds 0..7,999 (7,479 accepted at their first draw)

if __name__ == "__main__":  # python -m worldagent.envs.racing.open_repair: refit and rewrite INVERSE_FILE
    fitted, info = fit_inverse(np.arange(FIT_SEEDS))
    target = resources.files("worldagent.envs.racing").joinpath(INVERSE_FILE)
    np.savez(str(target), inverse=fitted)
    print(f"fitted on {info['tracks']:,} tracks; wrote {target}")
