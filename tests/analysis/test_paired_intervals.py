"""The paired intervals of ``worldagent diff`` (``analysis.diff``): Hall's skew-corrected mean difference and the CVaR tail warning."""

from __future__ import annotations

import numpy as np
from scipy.stats import t

from worldagent.analysis.diff import MIN_TAIL_WORLDS, hall_interval, paired_cvar, paired_difference
from worldagent.reports.diff import cvar_line


def collapses(rng, worlds: int) -> np.ndarray:
    """f64[W] per-world differences B − A of mean 0: +2, and a collapse of −20 on 10% of worlds (left-skewed)."""
    return 2.0 + rng.normal(0, 3.5, worlds) - 20.0 * (rng.random(worlds) < 0.1)


def plain_t(values: np.ndarray) -> tuple[float, float]:
    spread = t.ppf(0.975, len(values) - 1) * values.std(ddof=1) / np.sqrt(len(values))
    return values.mean() - spread, values.mean() + spread


def test_hall_leans_toward_the_skew_and_covers_more_than_t_at_30_worlds():
    rng = np.random.default_rng(0)
    values = collapses(rng, 30)
    (low, high), (t_low, t_high) = hall_interval(values), plain_t(values)
    assert low < t_low and high < t_high  # left-skewed differences: the interval reaches further left, less far right
    samples = [collapses(rng, 30) for _ in range(1500)]
    hall = np.mean([lo <= 0 <= hi for lo, hi in map(hall_interval, samples)])
    plain = np.mean([lo <= 0 <= hi for lo, hi in map(plain_t, samples)])
    assert hall > plain + 0.005 and hall > 0.925  # benchmarks/diff_coverage.py measures it with 20,000 replications


def test_hall_is_t_without_skew_and_a_point_without_spread():
    symmetric = np.array([-2.0, -1.0, 0.0, 1.0, 2.0])
    np.testing.assert_allclose(hall_interval(symmetric), plain_t(symmetric))
    found = paired_difference(np.zeros((6, 2)), np.full((6, 2), 1.5))
    assert (found["low"], found["difference"], found["high"]) == (1.5, 1.5, 1.5)


def test_a_cvar_from_a_small_tail_carries_a_warning_naming_the_fix():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(2, 200))
    small = paired_cvar(a, b, resamples=200)
    assert small["tail"] == 20 < MIN_TAIL_WORLDS and "pass --worlds 1000 or more" in small["warning"] and "\n" not in small["warning"]
    line = cvar_line({"cvar": {**small, "metric": "return"}})
    assert line.count("Warning: the α-CVaR interval rests on 20 tail worlds") == 1
    a, b = rng.normal(size=(2, 1000))
    large = paired_cvar(a, b, resamples=200)
    assert large["tail"] == 100 and large["warning"] is None and "Warning" not in cvar_line({"cvar": {**large, "metric": "return"}})
