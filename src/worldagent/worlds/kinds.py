"""What phase 1 needs to know about each environment's worlds, in one table.

A *world kind* says how to generate a batch of worlds from seeds (the procedural generator),
how to turn worlds into the VAE's binary cells (racing: the 64×64 track raster; harvest: the
wall and apple grids), and the shape of those cells for pictures.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from worldagent.errors import WorldagentError


@dataclass(frozen=True)
class WorldKind:
    """One environment's worlds.

    Attributes:
        name: "racing" or "harvest".
        generate: ``seeds int[N] -> batched world`` (numpy arrays, leading axis N).
        cells: ``batched world -> uint8[N, D]`` binary VAE input.
        cell_shape: the shape of one world's cells before flattening (for pictures).
    """

    name: str
    generate: Callable[[np.ndarray], Any]
    cells: Callable[[Any], np.ndarray]
    cell_shape: tuple[int, ...]

    @property
    def cell_count(self) -> int:
        return int(np.prod(self.cell_shape))


def _racing() -> WorldKind:
    from worldagent.envs.racing.tracks import generate_tracks
    from worldagent.envs.racing.world import RASTER_SIZE

    def cells(tracks) -> np.ndarray:
        raster = np.asarray(tracks.raster)
        return raster.reshape(len(raster), -1).astype(np.uint8)

    return WorldKind("racing", generate_tracks, cells, (RASTER_SIZE, RASTER_SIZE))


def _harvest() -> WorldKind:
    from worldagent.envs.harvest.maps import generate_maps
    from worldagent.envs.harvest.world import DEFAULT_SIZE

    def cells(maps) -> np.ndarray:
        grids = np.stack([np.asarray(maps.walls), np.asarray(maps.apples)], axis=1)  # [N, 2, H, W]
        return grids.reshape(len(grids), -1).astype(np.uint8)

    return WorldKind("harvest", generate_maps, cells, (2, DEFAULT_SIZE, DEFAULT_SIZE))


_KINDS = {"racing": _racing, "harvest": _harvest}
ENV_NAMES = tuple(_KINDS)


def world_kind(env: str) -> WorldKind:
    """The ``WorldKind`` of ``env``; unknown names get an error listing the known ones."""
    if env not in _KINDS:
        raise WorldagentError(f"unknown environment {env!r}; use one of: {', '.join(ENV_NAMES)}.")
    return _KINDS[env]()
