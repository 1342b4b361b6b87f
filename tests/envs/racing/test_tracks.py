"""Tests of the batched CarRacing track generator (worldagent.envs.racing.tracks)."""

from __future__ import annotations

import numpy as np
import pytest

from worldagent.envs.racing import tracks as T
from worldagent.envs.racing.world import HALF_WIDTH, MAX_EXTENT, NUM_POINTS, RASTER_SIZE, ROAD_SIZE, pixel_centres, to_pixel, unpack_road
from worldagent.errors import WorldagentError

# Seeds 36 and 313 are rejected once and twice by upstream before a track is accepted.
FIDELITY_SEEDS = [0, 1, 2, 7, 36, 100, 313, 999, 4242, 123456]


def exact_raster(centreline: np.ndarray, size: int) -> np.ndarray:
    """Brute force: every pixel centre against every segment of the closed loop."""
    a = np.asarray(centreline, dtype=np.float64)
    d = np.roll(a, -1, axis=0) - a
    p = pixel_centres(size).reshape(-1, 1, 2)
    t = np.clip(((p - a) * d).sum(-1) / (d * d).sum(-1), 0.0, 1.0)
    gap = p - (a + t[..., None] * d)
    return ((gap**2).sum(-1).min(axis=1) <= HALF_WIDTH**2).reshape(size, size)


def test_upstream_loop_equals_gymnasium_carracing():
    pytest.importorskip("Box2D")
    gymnasium = pytest.importorskip("gymnasium")
    env = gymnasium.make("CarRacing-v3")
    try:
        ours = T.upstream_loops(FIDELITY_SEEDS)
        for seed, loop in zip(FIDELITY_SEEDS, ours):
            env.reset(seed=seed)
            theirs = np.array(env.unwrapped.track, dtype=np.float64)
            assert loop.shape == theirs.shape, seed
            np.testing.assert_allclose(loop, theirs, rtol=0, atol=1e-9, err_msg=f"seed {seed}")
        np.testing.assert_array_equal(T.upstream_loop(FIDELITY_SEEDS[4]), ours[4])
    finally:
        env.close()


def test_retries_are_counted():
    _, retries = T.upstream_loops([0, 36, 313], return_retries=True)
    assert retries.tolist() == [0, 1, 2]


def test_same_seed_same_track_and_batch_equals_one_by_one(tracks, track):
    again = T.generate_tracks(np.arange(8))
    for name in ("centreline", "raster", "road"):
        np.testing.assert_array_equal(getattr(again, name), getattr(tracks, name))
        np.testing.assert_array_equal(getattr(track, name), getattr(tracks, name)[0])
    one = T.generate_track(5)
    for name in ("centreline", "raster", "road"):
        np.testing.assert_array_equal(getattr(one, name), getattr(tracks, name)[5])


def test_different_seeds_give_different_tracks(tracks):
    flat = tracks.centreline.reshape(len(tracks.centreline), -1)
    for i in range(len(flat)):
        for j in range(i + 1, len(flat)):
            assert np.abs(flat[i] - flat[j]).max() > 0.05
            assert not np.array_equal(tracks.raster[i], tracks.raster[j])


def test_tracks_are_closed_evenly_sampled_and_inside_bounds(tracks, track):
    c = np.asarray(tracks.centreline, dtype=np.float64)
    assert tracks.centreline.dtype == np.float32 and c.shape == (8, NUM_POINTS, 2)
    assert tracks.raster.shape == (8, RASTER_SIZE, RASTER_SIZE) and tracks.raster.dtype == bool
    assert tracks.road.shape == (8, ROAD_SIZE, ROAD_SIZE // 32) and tracks.road.dtype == np.uint32
    steps = np.linalg.norm(np.roll(c, -1, axis=1) - c, axis=-1)  # the closing step K-1 -> 0 included
    arc = steps.max(axis=1, keepdims=True)  # chords of equal arc-length steps; corners shorten a few
    assert np.all(steps >= 0.97 * arc) and np.all(np.median(steps, axis=1) > 0.999 * arc[:, 0])
    assert np.all(np.abs(steps[:, -1] - np.median(steps, axis=1)) < 0.03 * arc[:, 0])  # closing step too
    assert np.abs(c).max() < MAX_EXTENT
    area = 0.5 * (c[..., 0] * np.roll(c[..., 1], -1, 1) - np.roll(c[..., 0], -1, 1) * c[..., 1]).sum(-1)
    assert np.all(area > 0)  # counter-clockwise, as upstream drives
    tracks.validate()
    track.validate()


def test_resample_loop_starts_at_point_zero_and_keeps_order():
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    out = T.resample_loop(square, 8)
    expected = [[0, 0], [0.5, 0], [1, 0], [1, 0.5], [1, 1], [0.5, 1], [0, 1], [0, 0.5]]
    np.testing.assert_allclose(out, expected, atol=1e-12)


def test_statistics_fall_in_documented_ranges():
    stats = T.track_statistics(np.arange(20_000, 20_200))  # seeds outside the measured 0..9999
    for name, (mean, std, low, high) in T.MEASURED_STATISTICS.items():
        values = stats[name]
        assert values.shape == (200,)
        assert abs(values.mean() - mean) < 4 * std / np.sqrt(200), name
        spread = high - low
        assert low - 0.25 * spread <= values.min() and values.max() <= high + 0.25 * spread, name
    assert stats["max_coord"].max() < MAX_EXTENT
    assert set(stats["summary"]) == {"points", "length", "turning", "max_coord"}
    loops = T.upstream_loops([3, 4])
    np.testing.assert_array_equal(T.track_statistics(loops)["length"], T.track_statistics([3, 4])["length"])


def test_raster_orientation_top_rows_are_positive_y(tracks):
    angle = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    circle = 0.2 * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    circle[:, 1] += 0.6  # high up: only the top rows
    raster = T.rasterize(circle, 64)
    rows = np.flatnonzero(raster.any(axis=1))
    assert rows.max() < 32 and rows.min() > 0
    c = np.asarray(tracks.centreline[0], dtype=np.float64)
    top, bottom = c[np.argmax(c[:, 1])], c[np.argmin(c[:, 1])]
    for size, grid in ((RASTER_SIZE, T.rasterize(tracks.centreline[0], RASTER_SIZE)), (ROAD_SIZE, unpack_road(tracks.road[0]))):
        row, col = np.rint(to_pixel(top, size)).astype(int)
        assert grid[row, col] and row - np.flatnonzero(grid.any(axis=1)).min() <= 1
        assert row < np.rint(to_pixel(bottom, size))[0] and row < size // 2


@pytest.mark.parametrize("index", [0, 3, 6])
def test_raster_matches_exact_distance_rule(tracks, index):
    c = tracks.centreline[index]
    np.testing.assert_array_equal(T.rasterize(c, RASTER_SIZE), exact_raster(c, RASTER_SIZE))
    np.testing.assert_array_equal(unpack_road(tracks.road[index]), exact_raster(c, ROAD_SIZE))


@pytest.mark.parametrize("index", [0, 3, 6])
def test_raster_is_the_footprint_road_and_enclosed_area(tracks, index):
    from matplotlib.path import Path as PolygonPath

    c = np.asarray(tracks.centreline[index], np.float64)
    inside = PolygonPath(c).contains_points(pixel_centres(RASTER_SIZE).reshape(-1, 2)).reshape(RASTER_SIZE, RASTER_SIZE)
    np.testing.assert_array_equal(T.fill_interior(c[None], RASTER_SIZE)[0], inside)
    np.testing.assert_array_equal(tracks.raster[index], inside | exact_raster(c, RASTER_SIZE))
    assert inside.sum() > 10 * exact_raster(c, RASTER_SIZE).sum() / 4  # filled, not just the road


@pytest.mark.parametrize(
    "call",
    [
        lambda: T.seeds_from(0, -1),
        lambda: T.seeds_from(0, 0),
        lambda: T.seeds_from(-1, 5),
        lambda: T.seeds_from(0.5, 3),
        lambda: T.seeds_from(0, 2.0),
        lambda: T.generate_tracks([1.5, 2.0]),
        lambda: T.generate_tracks([3, -1]),
        lambda: T.generate_tracks([]),
        lambda: T.generate_tracks([[1, 2]]),
        lambda: T.generate_tracks([True]),
        lambda: T.generate_track(1.0),
        lambda: T.upstream_loop(-3),
        lambda: T.generate_tracks([1], num_points=4),
        lambda: T.resample_loop(np.zeros((5, 3)), 8),
        lambda: T.resample_loop(np.zeros((5, 2)), 8),
        lambda: T.rasterize(np.zeros((2, 5, 3)), 64),
        lambda: T.rasterize(np.full((1, 5, 2), np.nan), 64),
    ],
)
def test_bad_input_raises_one_line_error(call):
    with pytest.raises(WorldagentError) as info:
        call()
    assert "\n" not in str(info.value)


def test_seeds_from():
    np.testing.assert_array_equal(T.seeds_from(10, 3), [10, 11, 12])
    assert T.seeds_from(0, 4).dtype == np.int64
