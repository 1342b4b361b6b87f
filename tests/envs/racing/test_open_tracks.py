"""Racing's open repair: checkpoints read off a footprint, a new valid track built from them."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from worldagent.envs.racing import open_repair, tracks, walker
from worldagent.envs.racing.open_repair import OpenTracks
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


def test_the_shipped_map_is_a_least_squares_fit_of_the_same_features(repaired):
    refit, info = open_repair.fit_inverse(np.arange(300), chunk=300)
    shipped = open_repair.load_inverse()
    assert info["tracks"] > 250 and refit.shape == shipped.shape
    probe = open_repair._features(jax.vmap(open_repair.profile)(jnp.asarray(repaired[0].raster, jnp.float32)))
    difference = np.abs(np.asarray(probe @ refit) - np.asarray(probe @ shipped))
    assert difference.mean() < 0.05  # on CarRacing tracks, 300 of them estimate the 7,479-track fit


def test_settings_are_refused():
    with pytest.raises(WorldagentError, match="no settings"):
        OpenTracks.from_dataset(None, {"apples": 3})
