"""Pictures of toy grids: one world as a PIL image, episodes on a matplotlib axis, a sheet."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from .world import START

FLOOR, WALL, GOAL, START_COLOUR = (235, 235, 235), (60, 60, 60), (40, 170, 70), (70, 110, 220)


def rgb(world) -> np.ndarray:
    """uint8[S, S, 3]: one world's cells coloured."""
    walls, goal = np.asarray(world.walls, bool), np.asarray(world.goal, bool)
    image = np.full((*walls.shape, 3), FLOOR, np.uint8)
    image[walls] = WALL
    image[goal] = GOAL
    image[START] = START_COLOUR
    return image


def world_picture(world, size: int) -> Image.Image:
    """One (unbatched) world, ``size`` pixels square."""
    return Image.fromarray(rgb(world)).resize((size, size), Image.NEAREST)


def draw_episodes(axis, world, episodes) -> None:
    """The world with each replayed episode's path (``Episodes.positions`` are (row, col) cells)."""
    axis.imshow(rgb(world), interpolation="nearest")
    for episode in range(len(episodes)):
        path = np.asarray(episodes.path(episode), np.float64)
        axis.plot(path[:, 1], path[:, 0], "-o", markersize=2, linewidth=1, alpha=0.7)
    axis.set_xticks([])
    axis.set_yticks([])


def sheet(worlds, path) -> Path:
    """Many worlds (batched) side by side on one PNG."""
    count = len(np.asarray(worlds.walls))
    tiles = [np.pad(rgb(_index(worlds, i)), ((1, 1), (1, 1), (0, 0)), constant_values=255) for i in range(count)]
    path = Path(path)
    Image.fromarray(np.concatenate(tiles, axis=1)).resize((count * 45, 45), Image.NEAREST).save(path)
    return path


def _index(worlds, i):
    return type(worlds)(walls=np.asarray(worlds.walls)[i], goal=np.asarray(worlds.goal)[i])
