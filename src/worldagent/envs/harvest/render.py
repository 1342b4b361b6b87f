"""Pictures of Resource Harvest in the style of the paper's Figure 5 (Pillow only).

Red agents (the observing agent blue, with its observation window dashed in white), green
apples, grey walls, on black. A thin dark notch marks each agent's heading. Files are written
atomically (temp file + rename).
"""

from __future__ import annotations

import math
from pathlib import Path

import jax
import numpy as np
from PIL import Image, ImageDraw

from worldagent.envs.harvest.env import HEADING_STEP, Harvest, HarvestState
from worldagent.envs.harvest.world import HarvestMap, spawn_corners
from worldagent.files import save_png, write_atomically

BACKGROUND = (0, 0, 0)
WALL = (128, 128, 128)
APPLE = (40, 190, 60)
AGENT = (220, 40, 40)
OBSERVER = (40, 90, 230)
WINDOW = (255, 255, 255)
REACH = (20, 30, 70)  # dark blue: where the tagger can go
AGENT_COLOURS = ((0.95, 0.25, 0.25), (0.25, 0.55, 1.0), (1.0, 0.65, 0.1), (0.85, 0.35, 0.95))  # TL, TR, BL, BR (trajectories)
AGENT_CSS = tuple("#" + "".join(f"{round(255 * v):02x}" for v in rgb) for rgb in AGENT_COLOURS)  # the same, for the explorer


def hex_colour(rgb: tuple[int, int, int]) -> str:
    return "#" + "".join(f"{v:02x}" for v in rgb)


# What each colour of ``draw_map(..., agents=True, reach=True)`` means (the explorer's legend of the world picture).
LEGEND = {
    hex_colour(WALL): "wall",
    hex_colour(APPLE): "apple at the start",
    hex_colour(BACKGROUND): "floor",
    hex_colour(REACH): "floor agent 0 can walk to (walls that shut it in show)",
    hex_colour(OBSERVER): "agent 0's spawn corner (top left; the tagger when one is set)",
    hex_colour(AGENT): "the other agents' spawn corners",
}


def draw_grid(walls: np.ndarray, apples: np.ndarray, cell: int = 16) -> Image.Image:
    """An RGB image of walls and apples (bool[H, W] each), ``cell`` pixels per cell."""
    rgb = np.zeros(walls.shape + (3,), np.uint8)
    rgb[:] = BACKGROUND
    rgb[np.asarray(apples, bool)] = APPLE
    rgb[np.asarray(walls, bool)] = WALL
    return Image.fromarray(np.kron(rgb, np.ones((cell, cell, 1), np.uint8)))


def _dashed_rectangle(draw: ImageDraw.ImageDraw, box, dash: int = 4) -> None:
    left, top, right, bottom = box
    for x0, y0, x1, y1 in ((left, top, right, top), (right, top, right, bottom), (right, bottom, left, bottom), (left, bottom, left, top)):
        length = max(abs(x1 - x0), abs(y1 - y0))
        for start in range(0, length, 2 * dash):
            end = min(start + dash, length)
            fx0, fx1 = start / max(length, 1), end / max(length, 1)
            draw.line((x0 + (x1 - x0) * fx0, y0 + (y1 - y0) * fx0, x0 + (x1 - x0) * fx1, y0 + (y1 - y0) * fx1), fill=WINDOW, width=1)


def draw_state(state: HarvestState, env: Harvest = Harvest(), observer: int | None = 0, cell: int = 16) -> Image.Image:
    """Figure 5 (left): one (unbatched) state; ``observer`` is drawn blue with its window."""
    state = jax.tree_util.tree_map(np.asarray, state)
    image = draw_grid(state.world.walls, state.apples, cell)
    draw = ImageDraw.Draw(image)
    notch = max(cell // 4, 1)
    for agent, ((row, col), heading, timer) in enumerate(zip(state.position, state.heading, state.tagged_timer)):
        if timer > 0:
            continue
        x, y = col * cell, row * cell
        draw.rectangle((x, y, x + cell - 1, y + cell - 1), fill=OBSERVER if agent == observer else AGENT)
        d_row, d_col = HEADING_STEP[heading]
        cx, cy = x + cell / 2 + d_col * (cell / 2 - notch / 2), y + cell / 2 + d_row * (cell / 2 - notch / 2)
        draw.rectangle((cx - notch / 2, cy - notch / 2, cx + notch / 2, cy + notch / 2), fill=BACKGROUND)
    if observer is not None and state.tagged_timer[observer] == 0:
        size, behind = env.view_size, env.view_behind
        ahead, half = size - 1 - behind, size // 2
        offsets = [(-ahead, -half), (-half, -behind), (-behind, -half), (-half, -ahead)]
        top, left = np.asarray(state.position[observer]) + offsets[int(state.heading[observer])]
        _dashed_rectangle(draw, (left * cell, top * cell, (left + size) * cell - 1, (top + size) * cell - 1))
    return image


def draw_observation(obs: np.ndarray, cell: int = 16) -> Image.Image:
    """Figure 5 (right): one agent's observation uint8[V, V, 4], heading up, itself blue."""
    obs = np.asarray(obs)
    size = obs.shape[0]
    image = draw_grid(obs[..., 0] > 0, obs[..., 1] > 0, cell)
    draw = ImageDraw.Draw(image)
    for row, col in zip(*np.nonzero(obs[..., 2])):
        draw.rectangle((col * cell, row * cell, (col + 1) * cell - 1, (row + 1) * cell - 1), fill=AGENT)
    if not obs[..., 3].any():
        return image
    draw.line((0, 0, size * cell, size * cell), fill=AGENT, width=2)  # tagged out: crossed through
    draw.line((0, size * cell, size * cell, 0), fill=AGENT, width=2)
    return image


def tagger_reach(walls: np.ndarray) -> np.ndarray:
    """bool[H, W]: the free cells agent 0 (the tagger) can walk to from its corner (4-connected)."""
    from scipy.ndimage import label

    regions, _ = label(~walls)
    return regions == regions[0, 0]


def draw_map(world: HarvestMap, cell: int = 16, agents: bool = True, reach: bool = False) -> Image.Image:
    """One (unbatched) map, with the four agents at their spawn corners if ``agents``; ``reach``
    tints the empty cells the tagger can walk to, so walls that isolate it show (Figure 8b)."""
    walls, apples = np.asarray(world.walls, bool), np.asarray(world.apples, bool)
    image = draw_grid(walls, apples, cell)
    if reach:
        tint = np.kron(tagger_reach(walls) & ~apples, np.ones((cell, cell), bool))
        pixels = np.asarray(image).copy()
        pixels[tint] = REACH
        image = Image.fromarray(pixels)
    if agents:
        draw = ImageDraw.Draw(image)
        for agent, (row, col) in enumerate(spawn_corners(*walls.shape)):
            colour = OBSERVER if agent == 0 else AGENT
            draw.rectangle((col * cell, row * cell, (col + 1) * cell - 1, (row + 1) * cell - 1), fill=colour)
    return image


def draw_map_sheet(maps: HarvestMap, path, cell: int = 8, gap: int = 4) -> Path:
    """A PNG sheet of a batch of maps (bool[B, H, W] each), laid out in a near-square grid.

    Agent 0 (top-left, the tagger in §6.2.2) is blue. Returns the path written.
    """
    walls = np.asarray(maps.walls, bool)
    count, height, width = walls.shape
    columns = max(1, math.ceil(math.sqrt(count)))
    rows = max(1, math.ceil(count / columns))
    sheet = Image.new("RGB", (columns * (width * cell + gap) + gap, rows * (height * cell + gap) + gap), (40, 40, 40))
    for index in range(count):
        tile = draw_map(HarvestMap(walls=walls[index], apples=np.asarray(maps.apples[index], bool)), cell)
        row, col = divmod(index, columns)
        sheet.paste(tile, (gap + col * (width * cell + gap), gap + row * (height * cell + gap)))
    return save_png(sheet, path)


def save_episode_gif(states: HarvestState, path, env: Harvest = Harvest(), observer: int | None = 0, cell: int = 8, fps: int = 10) -> Path:
    """An animated GIF of an episode from states stacked on a leading time axis ``[T, ...]``.

    States may lack their world (``core.rollout`` drops it); then pass one with ``world`` set,
    e.g. ``states.replace(world=world)`` with an unbatched ``world``.
    """
    length = np.shape(states.time)[0]
    world = states.world
    frames = []
    for t in range(length):
        frame = jax.tree_util.tree_map(lambda leaf: np.asarray(leaf)[t], states.replace(world=None))
        frame = frame.replace(world=world if np.ndim(world.walls) == 2 else jax.tree_util.tree_map(lambda w: w[t], world))
        frames.append(draw_state(frame, env, observer, cell).convert("P", palette=Image.Palette.ADAPTIVE, colors=16))
    save = lambda tmp: frames[0].save(tmp, format="GIF", save_all=True, append_images=frames[1:], duration=int(1000 / fps), loop=0)  # noqa: E731
    return write_atomically(path, save)


def visit_counts(episodes, shape: tuple[int, int]) -> np.ndarray:
    """i64[N, H, W]: how many steps each agent stood on each cell, over all episodes, while on the map."""
    counts = None
    for e in range(len(episodes)):
        path, present = episodes.path(e), episodes.present[e, : int(episodes.steps[e]) + 1]
        agents = path.shape[1]
        counts = np.zeros((agents, *shape), np.int64) if counts is None else counts
        for a in range(agents):
            cells = path[present[:, a], a]
            np.add.at(counts[a], (cells[:, 0], cells[:, 1]), 1)
    return counts


def _visit_tint(counts: np.ndarray) -> np.ndarray:
    """f[H, W, 3]: each cell in the colour of the agent that stood on it most, brighter the more often."""
    owner, total = counts.argmax(axis=0), counts.sum(axis=0)
    strength = np.log1p(total) / max(np.log1p(total.max()), 1e-9)
    tint = np.asarray(AGENT_COLOURS)[owner] * np.where(total > 0, 0.2 + 0.6 * strength, 0.0)[..., None]
    return np.where(total[..., None] > 0, tint, np.asarray(BACKGROUND) / 255)


def draw_episodes(axis, world: HarvestMap, episodes) -> None:
    """The map on a matplotlib ``axis``, each cell tinted by the agent that occupied it most.

    The tint goes under the walls and apples, so the map itself stays readable; squares mark
    the spawn corners and the legend gives each agent's mean return.

    Args:
        axis: a matplotlib axis.
        world: one (unbatched) map.
        episodes: ``evaluation.trajectories.Episodes`` replayed on it (positions i32[E, T+1, N, 2]).
    """
    from matplotlib.patches import Patch

    walls, apples = np.asarray(world.walls, bool), np.asarray(world.apples, bool)
    height, width = walls.shape
    extent = (0, width, height, 0)
    counts = visit_counts(episodes, (height, width))
    axis.imshow(_visit_tint(counts), extent=extent, interpolation="nearest")
    wall_layer = np.zeros((height, width, 4))
    wall_layer[walls] = (*(np.asarray(WALL) / 255), 1.0)
    axis.imshow(wall_layer, extent=extent, interpolation="nearest")
    rows, cols = np.nonzero(apples)
    axis.scatter(cols + 0.5, rows + 0.5, s=22, color=np.asarray(APPLE) / 255, edgecolors="black", linewidths=0.4, zorder=4)
    for a, (row, col) in enumerate(spawn_corners(height, width)):
        axis.scatter([col + 0.5], [row + 0.5], marker="s", s=60, color=AGENT_COLOURS[a], edgecolors="white", linewidths=1.2, zorder=5)
    axis.set_xlim(0, width)
    axis.set_ylim(height, 0)
    returns = np.asarray(episodes.metrics.get("returns", np.zeros((len(episodes), counts.shape[0]))), np.float64)
    handles = [Patch(color=AGENT_COLOURS[a], label=f"agent {a}: return {returns[:, a].mean():.1f}") for a in range(counts.shape[0])]
    handles.append(Patch(color=np.asarray(APPLE) / 255, label="apple site"))
    axis.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.02), ncol=3, fontsize=11, frameon=False)
