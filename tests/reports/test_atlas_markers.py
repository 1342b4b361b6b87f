"""The atlas figure marks each worst world inside the grid it draws (issue 42, item 7)."""

from __future__ import annotations

import numpy as np

from worldagent.reports.atlas import marker_at
from worldagent.search.atlas import Grid, cell_of


def test_worlds_outside_the_grid_are_marked_in_the_edge_cell_they_fill():
    grid = Grid(("curvature", "length"), (10, 10), ((0.0, 1.0), (2.0, 4.0)))
    outside = np.array([1.7, 1.0])  # past the high end of the first range, below the low end of the second
    assert marker_at(outside, grid) == (1.0, 2.0)
    # the mark lies in the cell the archive files the world under
    assert cell_of(grid, np.array([marker_at(outside, grid)])) == cell_of(grid, outside[None])
    assert marker_at(np.array([0.25, 3.5]), grid) == (0.25, 3.5)  # inside: where it is


def test_a_one_descriptor_atlas_is_marked_halfway_up():
    grid = Grid(("curvature",), (10,), ((0.0, 1.0),))
    assert marker_at(np.array([-3.0]), grid) == (0.0, 0.5)
