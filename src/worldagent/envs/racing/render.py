"""Pictures of racing worlds (paper Figures 1 and 4): grey road on green grass, a blue agent.

Everything is drawn with Pillow through ``world.to_pixel``, so pictures, rasters and the env's
observation windows share one orientation (north up). Drawing is done at 2× and downsampled,
which anti-aliases the road edges.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from worldagent.envs.racing.world import HALF_WIDTH, Track, to_pixel
from worldagent.errors import WorldagentError
from worldagent.files import save_png, write_atomically

GRASS = (102, 204, 102)
ROAD = (110, 110, 110)
START_LINE = (245, 245, 245)
AGENT = (30, 80, 230)
TRAIL = (60, 120, 255)
CRASH = (220, 40, 40)
SUPERSAMPLE = 2


def hex_colour(rgb: tuple[int, int, int]) -> str:
    return "#" + "".join(f"{v:02x}" for v in rgb)


# What each colour of ``draw_track`` means (the explorer's legend of the world picture).
LEGEND = {hex_colour(ROAD): "road", hex_colour(GRASS): "grass (off the road: a crash)", hex_colour(START_LINE): "start line"}


VIEW_EXTENT = 0.9  # pictures show the square [-0.9, 0.9]²: every generated track fits in it


def _xy_to_canvas(xy: np.ndarray, size: int) -> np.ndarray:
    """Normalised (x, y) -> Pillow (x, y) pixel coordinates on a ``size×size`` canvas."""
    row_col = to_pixel(np.asarray(xy) / VIEW_EXTENT, size)
    return np.stack([row_col[..., 1] + 0.5, row_col[..., 0] + 0.5], axis=-1)


def _road_edges(centreline: np.ndarray, half_width: float) -> tuple[np.ndarray, np.ndarray]:
    """Left and right road edges f64[K, 2] from per-vertex normals (like upstream's tiles)."""
    tangent = np.roll(centreline, -1, axis=0) - np.roll(centreline, 1, axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=-1, keepdims=True), 1e-9)
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=-1)
    return centreline + half_width * normal, centreline - half_width * normal


def track_image(
    track: Track,
    size: int = 256,
    trajectory: np.ndarray | None = None,
    agent: np.ndarray | None = None,
    crashed: bool = False,
) -> Image.Image:
    """Draw one track, optionally with a trajectory f[T, 2] and the agent at ``agent`` f[2].

    Returns:
        An RGB ``size×size`` Pillow image.
    """
    centreline = np.asarray(track.centreline, dtype=np.float64)
    if centreline.ndim != 2:
        raise WorldagentError(f"track_image draws one track; got centreline shape {centreline.shape} (index the batch first).")
    big = size * SUPERSAMPLE
    image = Image.new("RGB", (big, big), GRASS)
    draw = ImageDraw.Draw(image)
    left, right = (_xy_to_canvas(edge, big) for edge in _road_edges(centreline, HALF_WIDTH))
    radius = HALF_WIDTH / VIEW_EXTENT * big / 2
    for i in range(len(centreline)):
        j = (i + 1) % len(centreline)
        draw.polygon([tuple(left[i]), tuple(left[j]), tuple(right[j]), tuple(right[i])], fill=ROAD)
    for x, y in _xy_to_canvas(centreline, big):  # round joints on the outside of sharp turns
        draw.ellipse([x - radius, y - radius, x + radius, y + radius], fill=ROAD)
    draw.line([tuple(left[0]), tuple(right[0])], fill=START_LINE, width=max(1, big // 256))
    if trajectory is not None and len(trajectory) > 1:
        draw.line([tuple(p) for p in _xy_to_canvas(np.asarray(trajectory), big)], fill=TRAIL, width=max(1, big // 200))
    if agent is not None:
        x, y = _xy_to_canvas(np.asarray(agent, dtype=np.float64), big)
        r = max(3.0, 1.6 * radius)
        draw.ellipse([x - r, y - r, x + r, y + r], fill=CRASH if crashed else AGENT, outline=(255, 255, 255))
    return image.resize((size, size), Image.LANCZOS)


def draw_track_sheet(tracks: Track, out: Path | str, seeds=None, columns: int = 4, size: int = 192) -> Path:
    """Draw a batch of tracks (leading axis) as a labelled grid and write it to ``out`` (PNG)."""
    centrelines = np.asarray(tracks.centreline)
    if centrelines.ndim != 3:
        raise WorldagentError("draw_track_sheet needs a batch of tracks (centreline of shape (B, K, 2)).")
    count = len(centrelines)
    columns = max(1, min(columns, count))
    rows = -(-count // columns)
    label = 14
    sheet = Image.new("RGB", (columns * size, rows * (size + label)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    font = ImageFont.load_default()
    for i in range(count):
        tile = track_image(Track(centrelines[i], tracks.raster[i], tracks.road[i]), size=size)
        x, y = (i % columns) * size, (i // columns) * (size + label)
        sheet.paste(tile, (x, y + label))
        draw.text((x + 4, y + 1), f"seed {int(seeds[i])}" if seeds is not None else f"track {i}", fill=(0, 0, 0), font=font)
    return save_png(sheet, out)


def save_episode_gif(
    track: Track, positions: np.ndarray, out: Path | str, crashed: bool = False, size: int = 256, fps: int = 25, stride: int = 2
) -> Path:
    """Write an episode (positions f[T, 2] of the steps taken) as an animated GIF."""
    positions = np.asarray(positions)
    if positions.ndim != 2 or positions.shape[-1] != 2 or len(positions) == 0:
        raise WorldagentError(f"positions has shape {positions.shape}; expected (T, 2) with T >= 1.")
    frames_at = list(range(0, len(positions), stride))
    if frames_at[-1] != len(positions) - 1:
        frames_at.append(len(positions) - 1)
    frames = [track_image(track, size, positions[: t + 1], positions[t], crashed and t == len(positions) - 1) for t in frames_at]
    save = lambda tmp: frames[0].save(tmp, format="GIF", save_all=True, append_images=frames[1:], duration=int(1000 / fps), loop=0)  # noqa: E731
    return write_atomically(out, save)


def track_view(centreline: np.ndarray, extent: float = VIEW_EXTENT, margin: float = 0.08) -> tuple[np.ndarray, np.ndarray]:
    """A square view (lower, upper corners) around the track: small tracks are drawn large."""
    low, high = centreline.min(axis=0), centreline.max(axis=0)
    centre, half = (low + high) / 2, max(high - low) / 2 + margin
    half = min(half, extent)
    centre = np.clip(centre, -extent + half, extent - half)
    return centre - half, centre + half


def draw_episodes(axis, world: Track, episodes) -> None:
    """The track on a matplotlib ``axis`` with one path per episode and crash points marked.

    Args:
        axis: a matplotlib axis.
        world: one (unbatched) track.
        episodes: ``evaluation.trajectories.Episodes`` replayed on it (positions f32[E, T+1, 2]).
    """
    from matplotlib import colormaps

    extent = (-VIEW_EXTENT, VIEW_EXTENT, -VIEW_EXTENT, VIEW_EXTENT)
    axis.imshow(np.asarray(track_image(world, 480)), extent=extent, origin="upper", interpolation="bilinear")
    colours, count = colormaps["plasma"], len(episodes)
    for e in range(count):
        path = episodes.path(e)
        axis.plot(path[:, 0], path[:, 1], color=colours(0.1 + 0.75 * e / max(count - 1, 1)), linewidth=1.3, alpha=0.85)
    crashes = np.asarray(episodes.metrics.get("crashed", np.zeros(count)), bool)
    crashed = [episodes.path(e)[-1] for e in range(count) if crashes[e]]
    if crashed:
        points = np.array(crashed)
        axis.scatter(
            points[:, 0], points[:, 1], marker="X", s=110, color=(0.9, 0.1, 0.1), edgecolors="white", linewidths=1.2, zorder=5, label="crash"
        )
    centreline = np.asarray(world.centreline)
    start, ahead = centreline[0], centreline[min(6, len(centreline) - 1)]
    axis.scatter([start[0]], [start[1]], marker="o", s=45, color="white", edgecolors="black", zorder=6, label="start")
    axis.annotate("", xy=tuple(ahead), xytext=tuple(start), arrowprops={"arrowstyle": "->", "color": "white", "linewidth": 1.5}, zorder=6)
    axis.legend(loc="lower right", fontsize=11, framealpha=0.8)
    lower, upper = track_view(centreline, VIEW_EXTENT)
    axis.set_xlim(lower[0], upper[0])
    axis.set_ylim(lower[1], upper[1])
