"""Repair makes every decoded world valid (paper §4.2, §5.2.1)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from worldagent.envs.harvest.repair import HarvestRepair, repair_maps
from worldagent.envs.harvest.spec import tagger_isolated
from worldagent.envs.harvest.world import DEFAULT_SIZE, HarvestMap, spawn_corners
from worldagent.envs.repairs import NearestWorld, nearest_index
from worldagent.errors import WorldagentError

SIZE = DEFAULT_SIZE
repair = jax.jit(repair_maps, static_argnums=1)


def test_a_tracks_own_raster_maps_to_itself(racing_data):
    rasters = jnp.asarray(racing_data.cells, jnp.float32)
    confident = 10.0 * (2.0 * rasters - 1.0)  # the raster itself, as sharp logits
    np.testing.assert_array_equal(nearest_index(confident, rasters), np.arange(len(rasters)))


def test_any_logits_map_to_a_dataset_track_the_most_probable_one(racing_data):
    rasters = jnp.asarray(racing_data.cells, jnp.float32)
    logits = jax.random.normal(jax.random.key(0), (16, rasters.shape[1])) * 3.0
    index = np.asarray(nearest_index(logits, rasters))
    assert ((0 <= index) & (index < len(rasters))).all()
    log_likelihood = np.asarray(rasters) @ np.asarray(logits).T - np.logaddexp(0.0, np.asarray(logits)).sum(1)  # [N, B]
    np.testing.assert_array_equal(index, log_likelihood.argmax(axis=0))


def test_nearest_world_returns_the_dataset_worlds_under_jit(racing_data):
    subset = racing_data.subset(np.arange(32))
    nearest = NearestWorld.from_dataset(subset, {})
    logits = 10.0 * (2.0 * jnp.asarray(subset.cells[[5, 0, 31]], jnp.float32) - 1.0)
    tracks = jax.jit(lambda fix, logits: fix(logits))(nearest, logits)
    np.testing.assert_array_equal(np.asarray(tracks.centreline), subset.worlds.centreline[[5, 0, 31]])
    np.testing.assert_array_equal(nearest.indices(logits), [5, 0, 31])
    assert nearest.config == {} and NearestWorld.from_dataset(subset, nearest.config).cells.shape == (32, 64 * 64)


def test_folded_behind_a_linear_layer_the_repair_picks_the_same_worlds(racing_data):
    """``fold``: [h, 1] against the folded rows picks what h @ kernel + bias picks against the cells;
    the bias alone (a zero kernel) decides between tracks of different sizes."""
    repair = NearestWorld.from_dataset(racing_data)
    key_h, key_w, key_b = jax.random.split(jax.random.key(5), 3)
    hidden = jax.nn.relu(jax.random.normal(key_h, (32, 24)))
    cells = racing_data.cells.shape[1]
    weights = jax.random.normal(key_w, (24, cells))
    for kernel, bias in ((weights, 2.0 * jax.random.normal(key_b, (cells,))), (0 * weights, jnp.linspace(-1, 1, cells))):
        folded = repair.fold(kernel, bias)
        augmented = jnp.concatenate([hidden, jnp.ones((32, 1))], axis=1)
        np.testing.assert_array_equal(folded.indices(augmented), repair.indices(hidden @ kernel + bias))


def test_harvest_repair_from_a_dataset(harvest_data):
    default = HarvestRepair.from_dataset(harvest_data, {})
    median = int(np.median(harvest_data.worlds.apples.reshape(len(harvest_data), -1).sum(1)))
    assert default.config == {"apples": median, "walls": "nearest"} and default.grid == (SIZE, SIZE)
    again = HarvestRepair.from_dataset(harvest_data, default.config)
    assert again.config == default.config and np.array_equal(again.layouts, default.layouts)
    assert len(default.layouts) == len(np.unique(harvest_data.worlds.walls.reshape(len(harvest_data), -1), axis=0))
    logits = jax.random.normal(jax.random.key(2), (4, 2 * SIZE * SIZE))  # flat, as the decoder gives them
    maps = jax.jit(lambda fix, logits: fix(logits))(HarvestRepair.from_dataset(harvest_data, {"apples": 12}), logits)
    for i in range(4):
        assert_valid_with_k_apples(maps.walls[i], maps.apples[i], 12)
    with pytest.raises(WorldagentError, match=f"apples=10000; pick between 1 and {SIZE * SIZE - 4}"):
        HarvestRepair.from_dataset(harvest_data, {"apples": 10_000})


def assert_valid_with_k_apples(walls, apples, k):
    walls, apples = np.asarray(walls), np.asarray(apples)
    HarvestMap(walls=walls, apples=apples).validate()  # free corners, no apple in a wall
    assert apples.sum() == k
    rows, cols = spawn_corners(SIZE, SIZE).T
    assert not walls[rows, cols].any() and not apples[rows, cols].any()


@pytest.mark.parametrize("fill", [0.0, 1.0, -1.0, 1e9, -1e9])
@pytest.mark.parametrize("k", [1, 30, 200])
def test_constant_logits_give_valid_maps(fill, k):
    logits = jnp.full((2, SIZE, SIZE), fill)
    repaired = repair(logits, k)
    assert_valid_with_k_apples(repaired.walls, repaired.apples, k)


def test_all_walls_are_cleared_only_where_apples_must_go():
    logits = jnp.stack([jnp.full((SIZE, SIZE), 5.0), jnp.zeros((SIZE, SIZE))])
    logits = logits.at[0, 3, 4].set(0.5)  # the least confident wall goes first
    repaired = repair(logits, 1)
    assert bool(repaired.apples[3, 4]) and int(repaired.walls.sum()) == SIZE * SIZE - 4 - 1


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), scale=st.floats(0.01, 100.0), k=st.sampled_from([1, 28, 300]))  # K is static
def test_random_logits_give_valid_maps_with_exactly_k_apples(seed, scale, k):
    logits = scale * jax.random.normal(jax.random.key(seed), (2, SIZE, SIZE))
    repaired = repair(logits, k)
    assert_valid_with_k_apples(repaired.walls, repaired.apples, k)
    walls = np.array(logits[0] > 0)
    walls[tuple(spawn_corners(SIZE, SIZE).T)] = False
    np.testing.assert_array_equal(repaired.walls, walls & ~np.asarray(repaired.apples))  # walls kept unless cleared for apples


def test_repair_batches():
    logits = jax.random.normal(jax.random.key(1), (6, 2, SIZE, SIZE))
    batched = repair(logits, 20)
    for i in range(6):
        single = repair(logits[i], 20)
        np.testing.assert_array_equal(batched.apples[i], single.apples)


def test_harvest_walls_snap_to_the_most_probable_dataset_layout(harvest_data):
    fix = HarvestRepair.from_dataset(harvest_data, {"apples": 12})
    walls = harvest_data.worlds.walls.reshape(len(harvest_data), -1).astype(np.float32)
    chosen = [3, 0, 77]
    logits = np.zeros((3, 2, SIZE * SIZE), np.float32)
    logits[:, 0] = 6.0 * (2.0 * walls[chosen] - 1.0)  # a dataset layout, as confident logits
    logits[:, 0] += np.random.default_rng(0).normal(0.0, 1.0, logits[:, 0].shape)  # blurred
    maps = jax.jit(lambda fix, logits: fix(logits))(fix, jnp.asarray(logits.reshape(3, -1)))
    np.testing.assert_array_equal(np.asarray(maps.walls).reshape(3, -1), walls[chosen] > 0)
    for i in range(3):
        assert_valid_with_k_apples(maps.walls[i], maps.apples[i], 12)


def test_a_gappy_wall_snaps_to_the_closed_room_not_the_open_map():
    """Thresholding a wall the decoder is unsure of leaves gaps; snapping restores the room."""
    room = HarvestMap.from_str("\n".join(["....#" + "." * (SIZE - 5)] * 4 + ["#####" + "." * (SIZE - 5)] + ["." * SIZE] * (SIZE - 5)))
    open_map = HarvestMap(walls=np.zeros((SIZE, SIZE), bool), apples=np.zeros((SIZE, SIZE), bool))
    layouts = jnp.asarray(np.stack([room.walls, open_map.walls]).reshape(2, -1).astype(np.float32))
    wall_logit = np.where(room.walls, 2.0, -4.0)
    wall_logit[4, 1] = wall_logit[2, 4] = -0.5  # two unsure wall cells: thresholding opens the room
    logits = jnp.asarray(np.stack([wall_logit, np.zeros((SIZE, SIZE))]))
    thresholded, snapped = repair(logits, 5), repair_maps(logits, 5, layouts)
    assert tagger_isolated(room) == 1.0 and tagger_isolated(thresholded) == 0.0  # the gaps open the room
    np.testing.assert_array_equal(snapped.walls, room.walls)


def test_harvest_repair_config_is_checked_and_threshold_mode_kept(harvest_data):
    threshold = HarvestRepair.from_dataset(harvest_data, {"walls": "threshold"})
    assert threshold.layouts is None and threshold.config["walls"] == "threshold"
    assert HarvestRepair.from_dataset(harvest_data, threshold.config) == threshold
    with pytest.raises(WorldagentError, match="walls='curvy'; pick one of nearest, threshold"):
        HarvestRepair.from_dataset(harvest_data, {"walls": "curvy"})
    with pytest.raises(WorldagentError, match=r"unknown harvest repair setting\(s\) \['colour'\]"):
        HarvestRepair.from_dataset(harvest_data, {"colour": 1})
