"""Sample efficiency against the random distribution (paper §6.1.3): hand-computed counts."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from worldagent.errors import WorldagentError
from worldagent.reports.comparison import (
    best_so_far,
    censored_median,
    comparison_csv,
    comparison_figure,
    comparison_table_markdown,
    evaluations_to_reach,
    sample_efficiency,
    tail_fraction,
)

RANDOM = np.arange(100.0)  # quantiles 0.1, 0.05, 0.01 -> 9.9, 4.95, 0.99 (linear interpolation)
RUNS = {
    "a": [np.array([50.0, 20, 9, 3, 0]), np.array([40.0, 30, 8, 7, 6])],
    "b": [np.array([60.0, 70, 80])],
}


def test_counts_medians_and_never_reached_seeds_by_hand():
    a, b = sample_efficiency(RUNS, RANDOM)
    assert a["threshold_q0.1"] == pytest.approx(9.9) and a["threshold_q0.01"] == pytest.approx(0.99)
    assert a["reach_q0.1"] == [3, 3] and a["median_q0.1"] == 3 and a["never_q0.1"] == 0
    assert a["reach_q0.05"] == [4, None] and a["median_q0.05"] is None and a["never_q0.05"] == 1  # half never: no median
    assert a["reach_q0.01"] == [5, None] and a["never_q0.01"] == 1
    assert a["best_mean"] == pytest.approx(3.0) and a["best_sd"] == pytest.approx(np.sqrt(18.0))
    assert a["mean_sampled"] == pytest.approx(17.3) and a["evaluations"] == 5 and a["seeds"] == 2
    assert b["reach_q0.1"] == [None] and b["median_q0.1"] is None and b["never_q0.1"] == 1
    assert b["best_mean"] == 60.0 and np.isnan(b["best_sd"])  # one seed: no spread is invented


def test_maximising_targets_the_upper_tail():
    (row,) = sample_efficiency({"m": [np.array([10.0, 95, 99.5])]}, RANDOM, quantiles=(0.1, 0.01), maximize=True)
    assert row["threshold_q0.1"] == pytest.approx(89.1) and row["reach_q0.1"] == [2]
    assert row["threshold_q0.01"] == pytest.approx(98.01) and row["reach_q0.01"] == [3]
    assert row["best_mean"] == 99.5


def test_helpers_count_from_one_ignore_nan_and_censor_the_median():
    assert evaluations_to_reach(np.array([5.0, np.nan, 1.0]), 1.0, maximize=False) == 3
    assert evaluations_to_reach(np.array([np.nan, 2.0]), 1.0, maximize=False) is None
    assert censored_median([2, None, 5]) == 5  # the never-reached seed counts as later than any budget
    assert censored_median([2, None]) is None
    np.testing.assert_array_equal(best_so_far(np.array([3.0, np.nan, 1.0, 2.0]), maximize=False), [3, 3, 1, 1])
    np.testing.assert_array_equal(best_so_far(np.array([3.0, 5.0, 1.0]), maximize=True), [3, 5, 5])


def test_table_and_csv_say_never_instead_of_a_number():
    rows = sample_efficiency(RUNS, RANDOM)
    table = comparison_table_markdown(rows, "return")
    assert "| a | 2 | 5 | 3 | not reached (1/2 never) | not reached (1/2 never) | 3 ± 4.24 | 17.3 |" in table
    assert "≤ q0.1 (9.9)" in table and "1/q worlds on average (q0.1: 10, q0.05: 20, q0.01: 100)" in table
    csv = comparison_csv(rows)
    assert "4;never" in csv and "not reached" in csv


def test_tail_fraction_places_scores_in_the_random_tail():
    np.testing.assert_allclose(tail_fraction(np.array([-1.0, 0.0, 9.0, 99.0]), RANDOM, maximize=False), [0.0, 0.01, 0.1, 1.0])
    np.testing.assert_allclose(tail_fraction(np.array([100.0, 99.0, 90.0]), RANDOM, maximize=True), [0.0, 0.01, 0.1])


def test_bad_input_is_refused():
    with pytest.raises(WorldagentError, match="no finite value"):
        sample_efficiency(RUNS, np.array([np.nan]))
    with pytest.raises(WorldagentError, match="strictly between 0 and 1"):
        sample_efficiency(RUNS, RANDOM, quantiles=(1.5,))
    with pytest.raises(WorldagentError, match="without evaluations"):
        sample_efficiency({"a": [np.array([])]}, RANDOM)


def test_the_figure_is_a_png(tmp_path):
    out = comparison_figure(RUNS, RANDOM, "return", tmp_path / "fig" / "comparison.png")
    assert out.stat().st_size > 10_000
    outliers = {"a": [np.array([-300.0, *np.linspace(40, 60, 30)])]}  # a far outlier is noted, not squashing the bulk
    out = comparison_figure(outliers, np.linspace(40, 60, 200), "return", tmp_path / "outliers.png", maximize=True)
    assert out.stat().st_size > 10_000
    with Image.open(out) as image:
        assert image.format == "PNG" and image.size[0] > image.size[1] > 300


def test_the_best_so_far_panel_draws_each_optimisers_confirmed_world_where_the_random_tail_puts_it():
    from worldagent.reports.comparison import _best_so_far_panel
    from worldagent.reports.figures import _pyplot

    plt = _pyplot()
    figure, axis = plt.subplots()
    rows = [  # confirmed means with their intervals, on RANDOM = 0..99: shares (v + 1) / 100 of random worlds at or below
        {"optimiser": "b", "confirmed_mean": 49.0, "confirmed_mean_low": 29.0, "confirmed_mean_high": 69.0},
        {"optimiser": "a", "confirmed_mean": 9.0, "confirmed_mean_low": 4.0, "confirmed_mean_high": 19.0},
    ]
    _best_so_far_panel(axis, RUNS, RANDOM, "return", False, plt.get_cmap("tab10"), rows)
    bars = [c for c in axis.containers if c.has_yerr]
    assert len(bars) == 2
    for bar, (mean, low, high) in zip(bars, [(0.5, 0.3, 0.7), (0.1, 0.05, 0.2)]):
        (y,) = bar.lines[0].get_ydata()
        segment = bar.lines[2][0].get_segments()[0]
        assert y == pytest.approx(mean) and sorted(segment[:, 1]) == pytest.approx([low, high])
    assert bars[0].lines[0].get_color() == plt.get_cmap("tab10")(1)  # b's colour: its curve's, not its row's place
    plt.close(figure)
