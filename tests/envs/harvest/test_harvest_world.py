"""The harvest map pytree: text form, validation, one-line errors."""

from __future__ import annotations

import numpy as np
import pytest

from worldagent.envs.harvest.world import HarvestMap, empty_map, spawn_corners
from worldagent.errors import WorldagentError

FIXTURE = """
.....
.#A..
..A#.
.....
"""


def test_text_form_round_trips():
    world = HarvestMap.from_str(FIXTURE)
    assert world.shape == (4, 5)
    assert world.walls[1, 1] and world.walls[2, 3] and world.walls.sum() == 2
    assert world.apples[1, 2] and world.apples[2, 2] and world.apples.sum() == 2
    assert world.to_str() == FIXTURE.strip()
    world.validate()


def test_spawn_corners_are_the_four_corners_in_agent_order():
    assert spawn_corners(4, 5).tolist() == [[0, 0], [0, 4], [3, 0], [3, 4]]


@pytest.mark.parametrize(
    "text, message",
    [
        ("#....\n.....\n.....", "spawn corner"),
        (".....\n.....\n....A", "spawn corner"),
        ("..x..\n.....\n.....", "unknown characters"),
        ("....\n.....\n.....", "equal length"),
    ],
)
def test_bad_text_or_blocked_corner_is_a_one_line_error(text, message):
    with pytest.raises(WorldagentError, match=message) as error:
        HarvestMap.from_str(text).validate()
    assert "\n" not in str(error.value)


def test_wrong_shapes_are_rejected():
    with pytest.raises(WorldagentError, match="same shape"):
        HarvestMap(walls=np.zeros((5, 5), bool), apples=np.zeros((5, 6), bool)).validate()
    with pytest.raises(WorldagentError, match="same shape"):
        HarvestMap(walls=np.zeros(25, bool), apples=np.zeros(25, bool)).validate()
    with pytest.raises(WorldagentError, match="at least 3x3"):
        empty_map(2).validate()


def test_apples_in_walls_and_non_boolean_grids_are_rejected():
    walls = np.zeros((5, 5), bool)
    walls[2, 2] = True
    with pytest.raises(WorldagentError, match="apples inside walls"):
        HarvestMap(walls=walls, apples=walls.copy()).validate()
    with pytest.raises(WorldagentError, match="boolean"):
        HarvestMap(walls=np.full((5, 5), 0.5), apples=np.zeros((5, 5))).validate()
