"""Pictures of lava grids: one world as a PIL image, episodes on a matplotlib axis, a sheet."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from .world import START, LavaGrid

FLOOR, LAVA, GOAL, START_COLOUR = (235, 235, 235), (225, 90, 30), (40, 170, 70), (70, 110, 220)


def rgb(world: LavaGrid) -> np.ndarray:
    """uint8[S, S, 3]: one world's cells coloured."""
    lava, goal = np.asarray(world.lava, bool), np.asarray(world.goal, bool)
    image = np.full((*lava.shape, 3), FLOOR, np.uint8)
    image[lava] = LAVA
    image[goal] = GOAL
    image[START] = START_COLOUR
    return image


def world_picture(world: LavaGrid, size: int) -> Image.Image:
    """One (unbatched) world, ``size`` pixels square."""
    return Image.fromarray(rgb(world)).resize((size, size), Image.NEAREST)


def draw_episodes(axis, world: LavaGrid, episodes) -> None:
    """The world with each replayed episode's path (``Episodes.path(i)``: (row, col) cells)."""
    axis.imshow(rgb(world), interpolation="nearest")
    for episode in range(len(episodes)):
        path = np.asarray(episodes.path(episode), np.float64)
        axis.plot(path[:, 1], path[:, 0], "-o", markersize=2, linewidth=1, alpha=0.7)
    axis.set_xticks([])
    axis.set_yticks([])


def sheet(worlds: LavaGrid, path) -> Path:
    """Many worlds (batched) side by side on one PNG, 5 pixels a cell."""
    lava, goal = np.asarray(worlds.lava), np.asarray(worlds.goal)
    tiles = [np.pad(rgb(LavaGrid(lava=lava[i], goal=goal[i])), ((1, 1), (1, 1), (0, 0)), constant_values=255) for i in range(len(lava))]
    image = np.concatenate(tiles, axis=1)
    path = Path(path)
    Image.fromarray(image).resize((image.shape[1] * 5, image.shape[0] * 5), Image.NEAREST).save(path)
    return path
