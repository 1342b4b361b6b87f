"""Racing's open repair: checkpoints read off a footprint, a new valid track built from them."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from worldagent.envs.racing import open_repair, tracks, walker
from worldagent.envs.racing.open_repair import OpenTracks
from worldagent.envs.racing.world import NUM_POINTS, PLAYFIELD, RASTER_SIZE
from worldagent.errors import WorldagentError

BATCH = 32  # every call here decodes this many: one compile

decode = jax.jit(lambda repair, logits: repair(logits))


@pytest.fixture(scope="module")
def repair():
    return OpenTracks.from_dataset(None)


@pytest.fixture(scope="module")
def repaired(repair):
    """Tracks of seeds 500..531 (outside the fit's seeds) and the repair of their own footprints as confident logits."""
    shown = tracks.generate_tracks(np.arange(500, 532))
    logits = jnp.asarray(np.where(shown.raster.reshape(len(shown.raster), -1), 8.0, -8.0), jnp.float32)
    return shown, jax.tree_util.tree_map(np.asarray, decode(repair, logits))


def iou(a, b):
    return (a & b).sum(axis=(1, 2)) / (a | b).sum(axis=(1, 2))


def test_a_shown_track_is_rebuilt_close_to_itself_but_new(repaired):
    shown, rebuilt = repaired
    overlap = iou(rebuilt.raster, shown.raster)
    assert np.median(overlap) > 0.9 and overlap.min() > 0.7
    assert not any((a == b).all() for a, b in zip(rebuilt.raster, shown.raster))  # built, not looked up


def test_every_repaired_track_is_valid(repair, repaired):
    repaired[1].validate()
    noise = jax.random.normal(jax.random.key(0), (BATCH, 64 * 64)) * 4.0  # logits no decoder would give
    decode(repair, noise).validate()


@pytest.mark.integration
def test_a_rejected_draw_is_projected_to_an_accepted_one():
    loops, retries = tracks.upstream_loops(np.arange(40), return_retries=True)
    seed = int(np.flatnonzero(retries)[0])  # upstream redraws this seed's first checkpoints
    noise, rad = walker.draws([np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed)))])
    rejected = open_repair.to_unit(jnp.asarray(noise, jnp.float32), jnp.asarray(rad, jnp.float32))
    accepted = jnp.full_like(rejected, 0.3)  # a set the walker accepts, batched with it
    centre = jnp.full_like(rejected, 0.5)  # where every projection ends: the walker must accept it
    unit = jnp.concatenate([rejected, accepted, centre])
    lines, used, accepted = jax.jit(open_repair.project)(unit)  # the walker rejects row 0 as upstream does (test_walker.py)
    assert accepted.all()
    assert 0 < np.abs(np.asarray(used[0] - unit[0])).max() < 0.5  # moved, towards the centre, not to it
    np.testing.assert_array_equal(used[1], unit[1])  # an accepted set is kept
    jax.vmap(walker.track_from_centreline)(lines).validate()


UNIFORM_STD = 1 / np.sqrt(12)  # a uniform draw's std on the unit scale (0.289)


@pytest.fixture(scope="module")
def fresh():
    """Footprints f32[N, 64, 64] of CarRacing's tracks at 300 seeds past every dataset's (none fitted) whose first
    draws upstream accepts, and those draws f32[N, 20] on the unit scale."""
    seeds = np.arange(10_000, 10_300)
    loops, retries = tracks.upstream_loops(seeds, return_retries=True)
    lines = np.stack([tracks.resample_loop(loop[:, 2:], NUM_POINTS) for loop in loops]) / PLAYFIELD
    kept = retries == 0
    noise, rad = walker.draws([np.random.Generator(np.random.PCG64(np.random.SeedSequence(int(s)))) for s in seeds[kept]])
    truth = np.asarray(open_repair.to_unit(jnp.asarray(noise, jnp.float32), jnp.asarray(rad, jnp.float32)))
    return tracks.footprint(lines[kept].astype(np.float32), RASTER_SIZE).astype(np.float32), truth


def correlations(a, b):
    return np.array([np.corrcoef(a[:, i], b[:, i])[0, 1] for i in range(a.shape[1])])


def test_recovered_draws_spread_as_upstream_draws(repair, fresh):
    footprints, truth = fresh
    logits = jnp.asarray(np.where(footprints.reshape(len(footprints), -1) > 0, 30.0, -30.0), jnp.float32)
    read = np.asarray(jax.jit(lambda r, x: r.draws(x))(repair, logits))
    ratio = read.std(axis=0) / truth.std(axis=0)
    assert (np.abs(ratio - 1) < 0.2).all(), ratio.round(2)  # the least-squares map's angles: 0.3-0.4
    assert np.abs(truth.std(axis=0) / UNIFORM_STD - 1).max() < 0.2  # the truth is upstream's uniform draw
    corr = correlations(read, truth)
    assert corr[: walker.FREE].mean() > 0.6 and corr[walker.FREE :].mean() > 0.85  # spread that follows the track, not noise


def test_a_blurred_footprint_still_reads_as_spread_draws(repair, fresh):
    footprints, truth = fresh

    @jax.jit
    def read_blurred(repair, footprints):
        blur = open_repair._blur_matrix(jnp.float32(1.2))
        probabilities = jnp.clip(blur @ footprints @ blur.T, 0.0, 1.0)
        profiles = jax.vmap(open_repair.profile)(probabilities)
        measured = jax.vmap(open_repair.edge_blur)(probabilities, profiles)
        return repair.inverse(profiles, measured), measured

    read, measured = jax.tree_util.tree_map(np.asarray, read_blurred(repair, jnp.asarray(footprints)))
    assert abs(float(np.median(measured)) - 1.2) < 0.3  # the outline's blur, in pixels
    assert (np.abs(read.std(axis=0) / truth.std(axis=0) - 1) < 0.2).all()  # the map of its blur level, not the crisp one's
    assert correlations(read, truth)[walker.FREE :].mean() > 0.85


def test_a_map_in_the_old_format_is_refused_with_the_fix(tmp_path):
    path = tmp_path / "open_inverse.npz"
    np.savez(path, inverse=np.zeros((open_repair.ANGLES + 1, 20), np.float32))  # format 1: the least-squares matrix
    with pytest.raises(WorldagentError, match="format 1.*refit it with `python -m worldagent.envs.racing.open_repair`"):
        open_repair.load_inverse(path)


def test_a_saved_map_loads_as_it_was(repair, tmp_path):
    open_repair.save_inverse(repair.inverse, tmp_path / "map.npz")
    loaded = open_repair.load_inverse(tmp_path / "map.npz")
    for a, b in zip(jax.tree_util.tree_leaves(loaded), jax.tree_util.tree_leaves(repair.inverse)):
        np.testing.assert_array_equal(a, b)


def test_settings_are_refused():
    with pytest.raises(WorldagentError, match="no settings"):
        OpenTracks.from_dataset(None, {"apples": 3})
