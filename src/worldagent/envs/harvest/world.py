"""The Resource Harvest world: wall and apple grids as a fixed-shape pytree (paper §5.1.2).

Coordinates. A map is ``grid[row, col]`` with row 0 at the top and column 0 at the left, like
the racing rasters. Cells outside the grid behave as walls. The four agents spawn at the four
corners, in the fixed order top-left, top-right, bottom-left, bottom-right (agent 0, the tagging
agent of the paper's influencing experiment, is top-left as in Figure 8b). ``spawn_corners`` is
the one place that lists them.

Text form, for readable fixtures: one line per row, ``#`` a wall, ``A`` an apple, ``.`` empty;
blank lines and surrounding whitespace are ignored.
"""

from __future__ import annotations

import jax
import numpy as np
from flax import struct

from worldagent.errors import WorldagentError

# Grid side, cells. The paper does not give its map size. Tagging needs agents to meet, so what
# matters is the room each agent has: SSD's Harvest map gives 101 cells per agent (36x14 inside,
# 5 agents), Melting Pot's commons_harvest 62 (open, 18x24, 7 players) to 110 (its 2022 open map,
# 31x57, 16 players). 19x19 gives 90; the 25x25 we used before gave 156, and its tagger rarely
# met anyone (conflict 0.05 after 2,000 episodes against 0.13 at 19; docs/harvest.md).
DEFAULT_SIZE = 19
WALL_CHAR, APPLE_CHAR, EMPTY_CHAR = "#", "A", "."


def spawn_corners(height: int, width: int) -> np.ndarray:
    """int32[4, 2]: the (row, col) spawn cell of each agent: TL, TR, BL, BR."""
    return np.array([[0, 0], [0, width - 1], [height - 1, 0], [height - 1, width - 1]], dtype=np.int32)


@struct.dataclass
class HarvestMap:
    """One map (or a batch, with a leading axis on both fields).

    Attributes:
        walls: bool[H, W] wall cells.
        apples: bool[H, W] cells holding an apple at the start of an episode; apples only ever
            regrow on these cells.
    """

    walls: jax.Array
    apples: jax.Array

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the grid."""
        return tuple(np.shape(self.walls)[-2:])

    def validate(self) -> None:
        """Host-side check of shapes, dtypes and spawn corners; raises ``WorldagentError``."""
        walls, apples = np.asarray(self.walls), np.asarray(self.apples)
        if walls.ndim < 2 or walls.shape != apples.shape:
            raise WorldagentError(f"harvest map has walls {walls.shape} and apples {apples.shape}; expected two (H, W) grids of the same shape.")
        height, width = walls.shape[-2:]
        if height < 3 or width < 3:
            raise WorldagentError(f"harvest map is {height}x{width}; make it at least 3x3.")
        for name, grid in (("walls", walls), ("apples", apples)):
            if grid.dtype != np.bool_ and not np.isin(grid, (0, 1)).all():
                raise WorldagentError(f"harvest map {name} must be boolean (0/1); threshold it first.")
        walls, apples = walls.astype(bool), apples.astype(bool)
        if np.any(walls & apples):
            raise WorldagentError("harvest map has apples inside walls; clear apples from wall cells (repair the map).")
        rows, cols = spawn_corners(height, width).T
        if np.any(walls[..., rows, cols] | apples[..., rows, cols]):
            raise WorldagentError("harvest map blocks a spawn corner; the four corner cells must hold neither walls nor apples.")

    @classmethod
    def from_str(cls, text: str) -> HarvestMap:
        """Parse the text form (``#`` wall, ``A`` apple, ``.`` empty); rows must be equally long."""
        rows = [line.strip() for line in text.strip().splitlines() if line.strip()]
        if not rows or len({len(row) for row in rows}) != 1:
            raise WorldagentError("harvest map text must be non-empty rows of equal length.")
        grid = np.array([list(row) for row in rows])
        unknown = set(np.unique(grid)) - {WALL_CHAR, APPLE_CHAR, EMPTY_CHAR}
        if unknown:
            raise WorldagentError(f"harvest map text has unknown characters {sorted(unknown)}; use '#', 'A' and '.'.")
        return cls(walls=grid == WALL_CHAR, apples=grid == APPLE_CHAR)

    def to_str(self) -> str:
        """The text form of one (unbatched) map."""
        walls, apples = np.asarray(self.walls, bool), np.asarray(self.apples, bool)
        if walls.ndim != 2:
            raise WorldagentError(f"to_str draws one map; index the batch first (walls have shape {walls.shape}).")
        grid = np.where(walls, WALL_CHAR, np.where(apples, APPLE_CHAR, EMPTY_CHAR))
        return "\n".join("".join(row) for row in grid)


def empty_map(height: int = DEFAULT_SIZE, width: int | None = None) -> HarvestMap:
    """An open map with no walls and no apples (handy for tests)."""
    width = height if width is None else width
    return HarvestMap(walls=np.zeros((height, width), bool), apples=np.zeros((height, width), bool))


def index_maps(maps: HarvestMap, index) -> HarvestMap:
    """Map ``index`` (an int or slice) of a batch of maps."""
    return jax.tree_util.tree_map(lambda leaf: leaf[index], maps)
