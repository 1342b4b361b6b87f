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


def draw_map(world: HarvestMap, cell: int = 16, agents: bool = True) -> Image.Image:
    """One (unbatched) map, with the four agents at their spawn corners if ``agents``."""
    walls, apples = np.asarray(world.walls, bool), np.asarray(world.apples, bool)
    image = draw_grid(walls, apples, cell)
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
