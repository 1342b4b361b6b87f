"""No text of the atlas figures overprints another (issue 47 item 4): harvest's legends, one per example world, used to
run into each other's below the panels, and into the titles of the next row of the counterfactual figure."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from matplotlib.text import Text

from worldagent.envs import registry
from worldagent.envs.harvest.world import HarvestMap
from worldagent.evaluation.trajectories import Episodes
from worldagent.reports.atlas import draw_atlas, draw_counterfactuals
from worldagent.reports.figures import _pyplot, fit_legend
from worldagent.search.atlas import Archive, Grid

plt = _pyplot()  # files only (Agg), as the report draws them

SIZE, AGENTS = 19, 4


def harvest_panel(seed: int) -> tuple[HarvestMap, Episodes]:
    """A map and 2 replayed-like episodes of 30 steps, with returns of three digits (the widest legend labels)."""
    rng = np.random.default_rng(seed)
    world = HarvestMap(walls=rng.random((SIZE, SIZE)) < 0.1, apples=rng.random((SIZE, SIZE)) < 0.1)
    positions = rng.integers(0, SIZE, (2, 31, AGENTS, 2))
    returns = 100.0 + 900.0 * rng.random((2, AGENTS))
    return world, Episodes(positions, np.ones((2, 31, AGENTS), bool), np.full(2, 30), {"returns": returns})


def undrawn_tick_labels(figure) -> set[int]:
    """ids of the tick labels matplotlib keeps for ticks outside the view (they exist, placed off the axis, but are not drawn)."""
    hidden = set()
    for axes in figure.axes:
        for axis in (axes.xaxis, axes.yaxis):
            low, high = sorted(axis.get_view_interval())
            slack = 1e-9 * max(abs(low), abs(high), 1.0)
            for tick in axis.get_major_ticks() + axis.get_minor_ticks():
                if not low - slack <= tick.get_loc() <= high + slack:
                    hidden |= {id(tick.label1), id(tick.label2)}
    return hidden


def overprinted(figure) -> list[tuple[str, str]]:
    """Every pair of drawn texts whose boxes overlap by more than a pixel each way."""
    figure.canvas.draw()
    renderer, hidden = figure.canvas.get_renderer(), undrawn_tick_labels(figure)
    texts = [t for t in figure.findobj(Text) if t.get_visible() and t.get_text().strip() and id(t) not in hidden]
    boxes = [(t.get_text(), t.get_window_extent(renderer)) for t in texts]
    return [
        (a, b)
        for (a, one), (b, other) in itertools.combinations(boxes, 2)
        if one.x0 < other.x1 - 1 and other.x0 < one.x1 - 1 and one.y0 < other.y1 - 1 and other.y0 < one.y1 - 1
    ]


@pytest.fixture
def harvest():
    return registry.get("harvest")


def test_the_four_example_worlds_legends_do_not_overprint(harvest):
    grid = Grid(("wall_share", "apple_clustering"), (8, 10), ((0.0, 0.125), (1.25, 5.25)))
    measures = np.array([[0.01, 1.5], [0.11, 5.0], [0.06, 3.0], [0.02, 4.5]])
    archive = Archive(np.arange(4), np.arange(4), np.array([31.0, 121.4, 127.9, 61.4]), measures)
    summary = {"grid": grid, "archive": archive, "coverage": 0.04, "qd_score": 1.065e4, "distinct_failing": 3}
    figure = draw_atlas(summary, harvest, "group_reward", False, {pick: harvest_panel(pick) for pick in range(4)})
    assert overprinted(figure) == []
    legends = [axis.get_legend() for axis in figure.axes if axis.get_legend() is not None]
    assert len(legends) == 4 and all(len(legend.get_texts()) == AGENTS + 1 for legend in legends)  # each world keeps its returns
    plt.close(figure)


def test_rows_of_counterfactual_pairs_do_not_overprint(harvest):
    rows = [[(*harvest_panel(2 * r + c), f"{r + 1}{'ab'[c]}: fails (t = 0.594 on the segment)") for c in range(2)] for r in range(2)]
    figure = draw_counterfactuals(harvest, rows)
    assert overprinted(figure) == []
    plt.close(figure)


def test_the_check_sees_legends_that_overprint(harvest):
    """The env's own legend, in panels side by side, overprints its neighbour's (what the atlas did); fitted, it does not."""
    figure, axes = plt.subplots(1, 4, figsize=(16.8, 4.2))
    for seed, axis in enumerate(axes):
        harvest.pictures.episodes(axis, *harvest_panel(seed))
        axis.set_xticks([])  # as the atlas's panels: the legend sits where tick labels would
    assert overprinted(figure)
    for axis in axes:
        fit_legend(axis)
    assert overprinted(figure) == []
    plt.close(figure)
