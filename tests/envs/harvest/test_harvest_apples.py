"""Apples as the generator places them (``envs.harvest.apples``): clusters read off apple logits, valid maps,
deterministic and independent of batch-mates; the repairs' ``apples`` setting."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage

from worldagent.envs.harvest.apples import (
    CLUSTERS,
    SPREAD,
    Clusters,
    choose_clusters,
    cluster_apples,
    cluster_radii,
    disc_offsets,
    fit_shift,
    placed_apples,
    rooms_from_walls,
)
from worldagent.envs.harvest.maps import generate_layout
from worldagent.envs.harvest.open_repair import OpenRooms
from worldagent.envs.harvest.repair import HarvestRepair, median_apples
from worldagent.envs.harvest.world import DEFAULT_SIZE, HarvestMap, index_maps
from worldagent.errors import WorldagentError

SIZE = DEFAULT_SIZE
EIGHT = np.ones((3, 3), int)
CENTRES = ((4, 4), (4, 14), (14, 9))  # far apart: three separate clusters
BATCH = 16  # every compiled call below takes this batch: one compile each
cluster_apples_jit = jax.jit(jax.vmap(cluster_apples))
choose_jit = jax.jit(jax.vmap(choose_clusters))
choose_apart_jit = jax.jit(jax.vmap(lambda rooms, logit: choose_clusters(rooms, logit, apart=True)))
rooms_jit = jax.jit(jax.vmap(rooms_from_walls))


def open_rooms(batch: int) -> jnp.ndarray:
    """bool[B, 5, S, S]: one room, the whole grid (as a map with no regions)."""
    return jnp.zeros((batch, 5, SIZE, SIZE), bool).at[:, 4].set(True)


def peaked_logits(centres, radius: int, high: float = 6.0, low: float = -6.0) -> np.ndarray:
    """f32[S, S]: apple logits ``high`` on discs of ``radius`` around ``centres``, ``low`` elsewhere."""
    logit = np.full((SIZE, SIZE), low, np.float32)
    for row, col in centres:
        for dr, dc in disc_offsets(radius):
            logit[row + dr, col + dc] = high
    return logit


@jax.jit
def generator_rooms() -> jnp.ndarray:
    """bool[BATCH, 5, S, S]: the rooms of the generator's first BATCH layouts, and those layouts."""
    layouts = jax.vmap(lambda seed: generate_layout(jax.random.key(seed)))(jnp.arange(BATCH))
    return jnp.concatenate([layouts.group_masks & ~layouts.walls[:, None], ~layouts.group_masks.any(axis=1)[:, None]], axis=1), layouts


def test_logits_peaking_at_three_discs_give_three_clusters_there():
    logits = jnp.asarray(np.stack([peaked_logits(CENTRES, 1), peaked_logits(CENTRES, 2)] * (BATCH // 2)))
    apples = np.asarray(cluster_apples_jit(open_rooms(BATCH), logits))
    clusters = choose_jit(open_rooms(BATCH), logits)
    for i in range(2):
        assert ndimage.label(apples[i], EIGHT)[1] == 3  # one patch per peak, nothing elsewhere
        found = np.asarray(clusters.centre[i])
        assert sorted(divmod(int(c), SIZE) for c in found[found >= 0]) == sorted(CENTRES)
    # radius 2 peaks: three discs of 13 cells hold the generator's 90 %, all on the discs
    assert apples[1].sum() == round(0.9 * 3 * 13) and apples[1][peaked_logits(CENTRES, 2) < 0].sum() == 0


def test_spread_keeps_later_clusters_off_a_smeared_blob_but_finds_separate_peaks():
    blob = peaked_logits([(9, 9)], 3, high=2.0)  # one decoder smear, wider than any disc: logits 2 on a radius-3 disc
    peaks = peaked_logits(CENTRES, 1)
    logits = jnp.asarray(np.stack([blob, peaks] * (BATCH // 2)))
    touching, apart = choose_jit(open_rooms(BATCH), logits), choose_apart_jit(open_rooms(BATCH), logits)
    assert (np.asarray(touching.centre[0]) >= 0).sum() > 1  # "clusters" spends more on the smear's rim
    assert (np.asarray(apart.centre[0]) >= 0).sum() == 1  # "spread": one cluster, nothing may touch it
    found = np.asarray(apart.centre[1])
    assert sorted(divmod(int(c), SIZE) for c in found[found >= 0]) == sorted(CENTRES)  # separate peaks are still found


def test_fit_shift_matches_the_target_mean_and_grows_with_it():
    rooms, _ = generator_rooms()
    logits = jax.random.normal(jax.random.key(3), (BATCH, SIZE, SIZE)) * 2.0 - 3.0  # unsure everywhere, as a blurry decoder
    count = jax.jit(lambda shift: jax.vmap(lambda r, a: placed_apples(r, a, SPREAD, shift).sum())(rooms, logits).mean())
    unshifted = float(count(0.0))
    shifts = [fit_shift(rooms, logits, target) for target in (unshifted + 6.0, unshifted + 12.0)]
    assert 0.0 < shifts[0] < shifts[1]
    for shift, target in zip(shifts, (unshifted + 6.0, unshifted + 12.0)):
        assert abs(float(count(shift)) - target) <= 1.5  # the count moves in steps of whole clusters


def test_radii_split_half_and_half_by_how_much_each_rim_gains():
    ring = jnp.asarray([3.0, -1.0, 2.0, -4.0, -jnp.inf, -jnp.inf])
    centre = jnp.asarray([5, 6, 7, 8, -1, -1])
    clusters = Clusters(centre=centre, room=jnp.zeros(6, jnp.int32), ring=ring)
    np.testing.assert_array_equal(cluster_radii(clusters), [2, 1, 2, 1, 1, 1])  # 4 clusters: the 2 best rims grow
    losing = ring.at[2].set(-0.5)  # only one rim gains: the best two of four grow all the same
    np.testing.assert_array_equal(cluster_radii(clusters._replace(ring=losing)), [2, 1, 2, 1, 1, 1])
    odd = clusters._replace(centre=jnp.asarray([5, 6, 7, -1, -1, -1]), ring=losing)
    np.testing.assert_array_equal(cluster_radii(odd), [2, 1, 1, 1, 1, 1])  # 3 clusters: one grows by rank, none more gains
    np.testing.assert_array_equal(cluster_radii(odd._replace(ring=ring)), [2, 1, 2, 1, 1, 1])  # every rim that gains grows


def test_every_room_gets_one_to_three_clusters_and_apples_stay_in_rooms():
    rooms, _ = generator_rooms()
    logits = jax.random.normal(jax.random.key(1), (BATCH, SIZE, SIZE)) * 3.0 - 2.0
    clusters = choose_jit(rooms, logits)
    counts = np.zeros((BATCH, 5), int)
    for i, (room, centres) in enumerate(zip(np.asarray(clusters.room), np.asarray(clusters.centre))):
        np.add.at(counts[i], room[centres >= 0], 1)
    present = np.asarray(rooms.any(axis=(2, 3)))
    assert (counts[present] >= 1).all() and (counts[present] <= 3).all() and (counts[~present] == 0).all()
    apples = np.asarray(cluster_apples_jit(rooms, logits))
    assert not (apples & ~np.asarray(rooms.any(axis=1))).any()  # never on walls or entrances


def test_rooms_from_walls_find_the_generator_rooms():
    true, layouts = generator_rooms()
    found = np.asarray(rooms_jit(layouts.walls & ~layouts.entrances))
    same = [sorted(r.tobytes() for r in np.asarray(true[i]) if r.any()) == sorted(r.tobytes() for r in found[i] if r.any()) for i in range(BATCH)]
    assert np.mean(same) >= 0.8  # 90 % of 1,000 fresh layouts (a one-cell corridor's ends can pass for entrances)


def test_repairs_with_clusters_give_valid_maps_deterministic_and_batch_invariant(harvest_data):
    logits = jax.random.normal(jax.random.key(2), (6, 2 * SIZE * SIZE)) * 4.0 - 2.0
    for repair in (OpenRooms.from_dataset(harvest_data), HarvestRepair.from_dataset(harvest_data, {"apples": CLUSTERS})):
        run = jax.jit(lambda x, r=repair: r(x))
        maps = run(logits)
        for i in range(6):
            index_maps(maps, i).validate()  # free corners, no apple in a wall
        again = run(logits)
        mates = run(logits[::-1])  # the same worlds beside other batch-mates (the same shape: no second compile)
        for got in (again, jax.tree_util.tree_map(lambda leaf: leaf[::-1], mates)):
            np.testing.assert_array_equal(np.asarray(maps.apples), np.asarray(got.apples))
            np.testing.assert_array_equal(np.asarray(maps.walls), np.asarray(got.walls))
        assert len(set(np.asarray(maps.apples).sum(axis=(1, 2)).tolist())) > 1  # the count varies, as fresh maps' does


def test_apples_setting_of_both_repairs(harvest_data):
    assert OpenRooms.from_dataset(harvest_data).config["apples"] == SPREAD  # the open repair's default
    assert HarvestRepair.from_dataset(harvest_data).config["apples"] == median_apples(harvest_data.worlds)  # the paper's: K
    for saved in ({"apples": 12, "rounds": 1, "entrances": "posterior"}, {"apples": CLUSTERS, "rounds": 1, "entrances": "tempered"}):
        assert OpenRooms.from_dataset(harvest_data, saved).config == saved  # generators saved with top-K or clusters decode as they did
    assert HarvestRepair.from_dataset(harvest_data, {"apples": CLUSTERS}).config == {"apples": CLUSTERS, "walls": "nearest"}
    spread = HarvestRepair.from_dataset(harvest_data, {"apples": SPREAD, "apple_shift": 1.25})
    assert spread.config == {"apples": SPREAD, "apple_shift": 1.25, "walls": "nearest"}
    for bad in ("many", 2.5):
        with pytest.raises(WorldagentError, match="apples="):
            OpenRooms.from_dataset(harvest_data, {"apples": bad})


def test_apples_on_a_map_with_no_room_space_left_are_none():
    walls = np.ones((SIZE, SIZE), bool)
    walls[0, 0] = walls[0, -1] = walls[-1, 0] = walls[-1, -1] = False
    batch = jnp.asarray(np.stack([walls] * BATCH))
    apples = np.asarray(cluster_apples_jit(rooms_jit(batch), jnp.zeros((BATCH, SIZE, SIZE))))[0]
    assert apples.sum() == 0
    HarvestMap(walls=walls, apples=apples).validate()
