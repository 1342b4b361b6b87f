"""The JAX walker against upstream's generator (``tracks.py``, itself equal to gymnasium's CarRacing)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from worldagent.envs.racing import tracks, walker
from worldagent.envs.racing.world import NUM_POINTS, PLAYFIELD, RASTER_SIZE, ROAD_SIZE, pack_road

SEEDS = np.arange(40)


@pytest.fixture(scope="module")
def walked():
    """(noise, rad) of each seed's first draws, the JAX walker's (centrelines, accepted), and upstream's (loops, retries)."""
    rngs = [np.random.Generator(np.random.PCG64(np.random.SeedSequence(int(s)))) for s in SEEDS]
    noise, rad = walker.draws(rngs)
    lines, accepted = jax.jit(walker.build)(jnp.asarray(noise, jnp.float32), jnp.asarray(rad, jnp.float32))
    return np.asarray(lines), np.asarray(accepted), *tracks.upstream_loops(SEEDS, return_retries=True)


def test_the_walker_accepts_exactly_the_draws_upstream_accepts(walked):
    _, accepted, _, retries = walked
    assert not accepted.all()  # seeds of the sample that upstream redraws
    np.testing.assert_array_equal(accepted, retries == 0)


def test_the_walkers_tracks_are_upstreams_to_float32_rounding(walked):
    lines, accepted, loops, retries = walked
    for i in np.flatnonzero(accepted):
        expected = tracks.resample_loop(loops[i][:, 2:], NUM_POINTS) / PLAYFIELD
        assert np.abs(lines[i] - expected).max() < 1e-3


def test_the_rasters_equal_the_numpy_ones(walked):
    lines = walked[0][walked[1]]
    built = jax.jit(jax.vmap(walker.track_from_centreline))(jnp.asarray(lines))
    np.testing.assert_array_equal(np.asarray(built.raster), tracks.footprint(lines.astype(np.float64), RASTER_SIZE))
    np.testing.assert_array_equal(np.asarray(built.road), pack_road(tracks.rasterize(lines.astype(np.float64), ROAD_SIZE)))
