"""Pictures: orientation matches the raster convention, trajectories and GIFs are written."""

from __future__ import annotations

import numpy as np
from PIL import Image

from worldagent.envs.racing.render import AGENT, GRASS, ROAD, VIEW_EXTENT, draw_track_sheet, save_episode_gif, track_image


def colour_at(image: Image.Image, xy) -> np.ndarray:
    """RGB of the picture at normalised (x, y): column from x, row from y (north up)."""
    size = image.size[0]
    col = int((xy[0] / VIEW_EXTENT + 1) * size / 2)
    row = int((1 - xy[1] / VIEW_EXTENT) * size / 2)
    return np.asarray(image)[row, col].astype(int)


def test_road_is_drawn_where_the_centreline_is_north_up(track):
    image = track_image(track, size=256)
    north = track.centreline[np.argmax(track.centreline[:, 1])]
    assert np.abs(colour_at(image, north) - ROAD).max() < 30
    assert np.abs(colour_at(image, (0.0, 0.85)) - GRASS).max() < 5  # outside every track
    # The raster agrees: the northmost point lies in the upper half of the raster's rows.
    rows = np.nonzero(track.raster.any(axis=1))[0]
    assert rows.min() < track.raster.shape[0] // 2


def test_agent_and_trajectory_are_drawn(track):
    path = np.asarray(track.centreline[:40])
    image = track_image(track, size=256, trajectory=path, agent=path[-1])
    assert np.abs(colour_at(image, path[-1]) - AGENT).max() < 40


def test_sheet_and_gif_are_written(tmp_path, tracks, track):
    sheet = draw_track_sheet(tracks, tmp_path / "sheet.png", seeds=range(8), columns=4, size=96)
    with Image.open(sheet) as image:
        assert image.size == (4 * 96, 2 * (96 + 14))
    gif = save_episode_gif(track, np.asarray(track.centreline[:30]), tmp_path / "episode.gif", size=64)
    with Image.open(gif) as image:
        assert image.n_frames == 16  # every 2nd of 30 steps, plus the last


def test_draw_episodes_marks_paths_and_crashes(track):
    import jax
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from worldagent.envs.racing.render import draw_episodes, track_view
    from worldagent.evaluation.trajectories import Episodes

    path = np.asarray(track.centreline[:5], np.float32)
    episodes = Episodes(path[None], np.ones((1, 5), bool), np.array([4]), {"crashed": np.array([True]), "lap_completed": np.array([False])})
    figure, axis = plt.subplots()
    draw_episodes(axis, jax.tree_util.tree_map(np.asarray, track), episodes)
    assert len(axis.lines) == 1 and "crash" in [t.get_text() for t in axis.get_legend().get_texts()]
    lower, upper = track_view(np.asarray(track.centreline))
    assert np.all(lower >= -VIEW_EXTENT) and np.all(upper <= VIEW_EXTENT)
    plt.close(figure)
