"""Pictures of mazes: one world as a PIL image, episodes on a matplotlib axis, a sheet, and where trace positions fall.

Colours follow jaxued's renderer: grey walls, a green goal, a red agent (a triangle pointing its way).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from .world import SIZE, MazeWorld

FLOOR, WALL, GOAL, AGENT = (235, 235, 235), (100, 100, 100), (0, 200, 0), (220, 40, 40)
CELL_PX = 12  # pixels a cell when drawing the agent's triangle, before resizing
# The agent's triangle in a unit cell, pointing right; rotated a quarter turn clockwise per direction (right, down, left, up).
TRIANGLE = np.array([[0.85, 0.5], [0.2, 0.2], [0.2, 0.8]])
LEGEND = {"#646464": "wall", "#00c800": "goal", "#dc2828": "agent's start (pointing its way)"}


def rgb(world: MazeWorld) -> np.ndarray:
    """uint8[13, 13, 3]: one maze's cells coloured, the start included (a cell, no direction)."""
    image = np.full((SIZE, SIZE, 3), FLOOR, np.uint8)
    image[np.asarray(world.wall_map, bool)] = WALL
    (gx, gy), (ax, ay) = np.asarray(world.goal_pos), np.asarray(world.agent_pos)
    image[gy, gx] = GOAL
    image[ay, ax] = AGENT
    return image


def triangle(x: int, y: int, direction: int, cell: float) -> list[tuple[float, float]]:
    """The agent's triangle in cell (x, y) facing ``direction``, as pixel corners for a grid of ``cell``-pixel cells."""
    angle = np.pi / 2 * int(direction)  # image y points down, so a positive angle turns clockwise on screen
    centred = TRIANGLE - 0.5
    turned = centred @ np.array([[np.cos(angle), np.sin(angle)], [-np.sin(angle), np.cos(angle)]]) + 0.5
    return [((x + px) * cell, (y + py) * cell) for px, py in turned]


def world_picture(world: MazeWorld, size: int) -> Image.Image:
    """One (unbatched) maze, ``size`` pixels square: walls, goal, and the agent as a triangle pointing its start direction."""
    cells = rgb(world)
    ax, ay = np.asarray(world.agent_pos)
    cells[ay, ax] = FLOOR
    image = Image.fromarray(cells).resize((SIZE * CELL_PX, SIZE * CELL_PX), Image.NEAREST)
    ImageDraw.Draw(image).polygon(triangle(ax, ay, int(np.asarray(world.agent_dir)), CELL_PX), fill=AGENT)
    return image.resize((size, size), Image.NEAREST)


def draw_episodes(axis, world: MazeWorld, episodes) -> None:
    """The maze with each replayed episode's path (``Episodes.path(i)``: (row, col) cells), a cross where each ended."""
    axis.imshow(rgb(world), interpolation="nearest")
    for episode in range(len(episodes)):
        path = np.asarray(episodes.path(episode), np.float64)
        jitter = (episode - (len(episodes) - 1) / 2) * 0.04  # paths over the same cells stay apart
        axis.plot(path[:, 1] + jitter, path[:, 0] + jitter, "-", linewidth=1.2, alpha=0.8)
        axis.plot(path[-1, 1] + jitter, path[-1, 0] + jitter, "x", markersize=4, color="black")
    axis.set_xticks([])
    axis.set_yticks([])


def locate(positions, world: MazeWorld, size: int) -> np.ndarray:
    """f[..., 2] pixel (x, y) on ``world_picture(world, size)`` of trace positions f[..., 2] (row, col): cell centres."""
    del world
    positions = np.asarray(positions, np.float64)
    return (positions[..., ::-1] + 0.5) * (size / SIZE)


def sheet(worlds: MazeWorld, path) -> Path:
    """Many mazes (batched) side by side on one PNG, 5 pixels a cell."""
    count = len(np.asarray(worlds.agent_dir))
    one = lambda i: MazeWorld(*(np.asarray(field)[i] for field in (worlds.wall_map, worlds.goal_pos, worlds.agent_pos, worlds.agent_dir)))
    tiles = [np.pad(rgb(one(i)), ((1, 1), (1, 1), (0, 0)), constant_values=255) for i in range(count)]
    image = np.concatenate(tiles, axis=1)
    path = Path(path)
    Image.fromarray(image).resize((image.shape[1] * 5, image.shape[0] * 5), Image.NEAREST).save(path)
    return path
