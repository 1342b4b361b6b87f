"""The map generator (paper §5.2.1): determinism, free corners, walls that enclose regions."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from scipy import ndimage

from worldagent.envs.harvest.maps import MapConfig, generate_layout, generate_maps, seeds_from
from worldagent.envs.harvest.world import DEFAULT_SIZE, index_maps, spawn_corners
from worldagent.errors import WorldagentError

FOUR_NEIGHBOURS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]])


@pytest.fixture(scope="module")
def layouts():
    """Layouts of seeds 0..199 without entrances, and with an entrance wherever possible."""
    keys = jax.vmap(jax.random.key)(np.arange(200))
    closed = jax.jit(jax.vmap(lambda k: generate_layout(k, MapConfig(entrance_probability=0.0))))(keys)
    opened = jax.jit(jax.vmap(lambda k: generate_layout(k, MapConfig(entrance_probability=1.0))))(keys)
    return jax.tree_util.tree_map(np.asarray, closed), jax.tree_util.tree_map(np.asarray, opened)


def test_same_seed_same_map_whatever_the_batch(generated_maps):
    again = generate_maps(seeds_from(0, 64))
    np.testing.assert_array_equal(again.walls, generated_maps.walls)
    np.testing.assert_array_equal(again.apples, generated_maps.apples)
    alone = generate_maps([37])
    np.testing.assert_array_equal(alone.walls[0], generated_maps.walls[37])
    np.testing.assert_array_equal(alone.apples[0], generated_maps.apples[37])
    assert not np.array_equal(generated_maps.walls[0], generated_maps.walls[1]) or not np.array_equal(
        generated_maps.apples[0], generated_maps.apples[1]
    )


def test_maps_are_valid_with_free_spawn_corners(generated_maps):
    assert generated_maps.walls.shape == (64, DEFAULT_SIZE, DEFAULT_SIZE)
    rows, cols = spawn_corners(DEFAULT_SIZE, DEFAULT_SIZE).T
    assert not generated_maps.walls[:, rows, cols].any()
    assert not generated_maps.apples[:, rows, cols].any()
    assert not (generated_maps.walls & generated_maps.apples).any()
    for i in range(64):
        index_maps(generated_maps, i).validate()
    assert generated_maps.apples.sum(axis=(1, 2)).min() > 0


def test_zero_to_four_regions_occur(layouts):
    closed, _ = layouts
    groups = closed.group_masks.any(axis=(2, 3)).sum(axis=1)  # merged regions per map
    assert groups.min() == 0 and groups.max() >= 2
    assert (closed.walls.sum(axis=(1, 2)) == 0).mean() > 0.1  # maps with no region at all


def test_walls_border_each_region(layouts):
    closed, _ = layouts
    union = closed.group_masks.any(axis=1)
    assert not (closed.walls & ~union).any()  # walls only on regions
    padded = np.pad(union, ((0, 0), (1, 1), (1, 1)), constant_values=True)
    size = union.shape[-1]
    ring = [padded[:, 1 + dr : 1 + size + dr, 1 + dc : 1 + size + dc] for dr in (-1, 0, 1) for dc in (-1, 0, 1)]
    np.testing.assert_array_equal(closed.walls, union & ~np.all(ring, axis=0))  # exactly the border


def test_without_entrances_regions_are_sealed(layouts):
    closed, _ = layouts
    for walls, groups in zip(closed.walls, closed.group_masks):
        labels, _ = ndimage.label(~walls, FOUR_NEIGHBOURS)
        outside = ~groups.any(axis=0)
        for group in groups:
            inside = group & ~walls
            if inside.any():  # the interior touches no open cell outside its region
                assert not np.isin(labels[inside], labels[outside & ~walls]).any()


def test_entrances_open_each_region_with_one_cell(layouts):
    _, opened = layouts
    opened_any = 0
    for walls, groups, entrances in zip(opened.walls, opened.group_masks, opened.entrances):
        walls = walls & ~entrances
        labels, _ = ndimage.label(~walls, FOUR_NEIGHBOURS)
        outside = ~groups.any(axis=0)
        for group in groups:
            count = (entrances & group).sum()
            assert count <= 1
            if count:
                opened_any += 1
                assert np.isin(labels[group & ~walls & ~entrances], labels[outside]).any()
    assert opened_any > 50


def test_bad_seeds_and_settings_are_one_line_errors():
    with pytest.raises(WorldagentError, match="seeds"):
        generate_maps([-1])
    with pytest.raises(WorldagentError, match="1-d"):
        generate_maps([[1, 2]])
    with pytest.raises(WorldagentError, match="max_regions"):
        generate_maps([0], MapConfig(max_regions=5))
    with pytest.raises(WorldagentError, match="probability"):
        generate_maps([0], MapConfig(entrance_probability=2.0))


def test_grid_size_is_a_parameter():
    maps = generate_maps([0, 1], MapConfig(size=12, max_extent=8))
    assert maps.walls.shape == (2, 12, 12)
    index_maps(maps, 0).validate()
