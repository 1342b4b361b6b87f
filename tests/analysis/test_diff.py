"""Paired statistics of two agents on the same worlds (analysis.diff): exact values, edge cases, and coverage by simulation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats as scipy_stats

from worldagent.analysis import diff

Z95 = scipy_stats.norm.ppf(0.975)


def test_paired_difference_is_the_t_interval_of_per_world_differences():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(30, 4))
    b = a + 0.5 + rng.normal(scale=0.3, size=(30, 1))  # one shift per world: episodes averaged first
    found = diff.paired_difference(a, b)
    d = b.mean(axis=1) - a.mean(axis=1)
    low, high = scipy_stats.t.interval(0.95, len(d) - 1, loc=d.mean(), scale=scipy_stats.sem(d))
    assert found["difference"] == pytest.approx(d.mean()) and found["worlds"] == 30
    assert (found["low"], found["high"]) == pytest.approx((low, high))
    assert found["a"] == pytest.approx(a.mean()) and found["b"] == pytest.approx(b.mean())


def test_identical_agents_differ_by_exactly_zero():
    values = np.random.default_rng(1).normal(size=(20, 3))
    same = diff.paired_difference(values, values.copy())
    assert (same["difference"], same["low"], same["high"]) == (0.0, 0.0, 0.0)
    risk = diff.paired_cvar(values, values.copy())
    assert (risk["difference"], risk["low"], risk["high"]) == (0.0, 0.0, 0.0)
    fails = values.mean(axis=1) < 0
    failures = diff.paired_failures(fails, fails)
    assert failures["difference"]["value"] == 0.0 and failures["regressed"] == failures["improved"] == 0
    low, high = failures["difference"]["low"], failures["difference"]["high"]
    assert low < 0 < high and low == pytest.approx(-high)  # no discordant world: an interval about 0, not a point
    assert diff.paired_difference(values[:1], values[:1] + 1)["low"] != diff.paired_difference(values[:1], values[:1] + 1)["low"]  # NaN: one world


def test_tango_statistic_at_zero_is_mcnemars_and_the_interval_holds_the_estimate():
    for regressed, improved, n in [(5, 2, 50), (10, 0, 40), (3, 7, 100), (1, 1, 10), (0, 4, 20)]:
        low, high = diff.tango_interval(regressed, improved, n)
        estimate = (regressed - improved) / n
        assert -1 <= low <= estimate <= high <= 1
        mcnemar = (regressed - improved) / math.sqrt(regressed + improved)
        assert diff._tango_statistic(regressed, improved, n, 0.0) == pytest.approx(mcnemar)
        assert (low > 0 or high < 0) == (abs(mcnemar) > Z95)  # it excludes 0 exactly when McNemar's score test rejects
        swapped = diff.tango_interval(improved, regressed, n)
        assert swapped == pytest.approx((-high, -low))
    assert diff.tango_interval(30, 0, 30)[1] == 1.0


def test_exact_mcnemar_p_value_and_failure_counts():
    assert diff.mcnemar_p(5, 0) == pytest.approx(2 / 32)
    assert diff.mcnemar_p(0, 0) == 1.0
    fail_a = np.array([0, 0, 1, 1, 0, 0], bool)
    fail_b = np.array([1, 1, 1, 0, 0, 0], bool)
    found = diff.paired_failures(fail_a, fail_b)
    assert (found["regressed"], found["improved"], found["worlds"]) == (2, 1, 6)
    assert found["a"]["p"] == pytest.approx(2 / 6) and found["b"]["p"] == pytest.approx(3 / 6)
    assert found["difference"]["value"] == pytest.approx(1 / 6)
    assert found["difference"]["p_value"] == pytest.approx(diff.mcnemar_p(2, 1)) == 1.0
    with pytest.raises(ValueError):
        diff.paired_failures(fail_a, fail_b[:3])


def test_cvar_is_the_mean_of_the_worst_share_of_worlds():
    values = np.arange(20, dtype=float)[::-1]
    assert diff.cvar(values, 0.1) == pytest.approx(0.5)  # the lowest 2 of 20: 0 and 1
    assert diff.cvar(values, 0.05) == 0.0 and diff.cvar(values[:5], 0.1) == 15.0  # at least one world
    a = np.linspace(0, 1, 50)
    b = a.copy()
    b[:5] -= 10  # B collapses on A's worst worlds
    risk = diff.paired_cvar(a, b, seed=3)
    assert risk["difference"] == pytest.approx(-10) and risk["high"] < 0 and risk["tail"] == 5


def test_the_bca_interval_of_a_cvar_difference_uses_an_exact_jackknife():
    rng = np.random.default_rng(4)
    for worlds in (2, 3, 11, 60):
        values = np.round(rng.normal(size=worlds), 1)  # ties too
        slow = [diff.cvar(np.delete(values, i), 0.1) for i in range(worlds)]
        assert diff.leave_one_out_cvar(values, 0.1) == pytest.approx(slow)
    a = rng.gamma(2.0, 10.0, 400)
    b = a + 2.0 - 20.0 * (rng.random(400) < 0.1)
    risk = diff.paired_cvar(a, b, seed=0)
    assert risk["low"] < risk["difference"] < risk["high"] < 0
    resampled = rng.normal(size=4000)
    percentiles = tuple(np.quantile(resampled, [0.025, 0.975]))  # no bias (the median), no skew: plain percentiles
    assert diff.bca_interval(resampled, float(np.median(resampled)), np.zeros(0), 0.95) == pytest.approx(percentiles)


def test_regressed_worlds_rank_by_prior_likelihood_with_their_nearest_passing_world():
    latents = np.array([[3.0, 0.0], [0.5, 0.0], [1.0, 1.0], [0.6, 0.0], [2.9, 0.0], [0.5, 0.0]])
    fail_a = np.array([0, 0, 0, 0, 0, 0], bool)
    fail_b = np.array([1, 1, 0, 0, 0, 1], bool)  # worlds 0, 1 and 5 (world 5 is world 1 again) regressed
    rows = diff.regressed_ranking(fail_a, fail_b, latents, latents)
    assert [r["world"] for r in rows] == [1, 5, 0]  # likeliest first; ties keep their order
    assert rows[0]["log_prior"] == pytest.approx(-0.125 - math.log(2 * math.pi))
    assert [r["nearest_passing"] for r in rows] == [3, 3, 4]  # passing under B, never a failing world
    no_latents = diff.regressed_ranking(fail_a, fail_b, latents, None)
    assert [r["world"] for r in no_latents] == [0, 1, 5] and no_latents[0]["log_prior"] is None


def coverage(simulate, truth: float, replications: int, seed: int) -> float:
    """Share of ``replications`` intervals ``simulate(rng) -> (low, high)`` that hold ``truth``."""
    rng = np.random.default_rng(seed)
    hits = sum(low <= truth <= high for low, high in (simulate(rng) for _ in range(replications)))
    return hits / replications


def test_paired_intervals_cover_at_their_level_by_simulation():
    """400 replications each (benchmarks/diff_coverage.py runs more settings): the paired t interval on
    skewed, correlated per-world returns and Tango's on correlated failures both cover >= 93% at 95%."""
    worlds = 100

    def returns(rng):
        base = rng.gamma(2.0, 10.0, worlds)  # a world's difficulty, shared by both agents
        a = base[:, None] + rng.normal(0, 5, (worlds, 4))
        b = base[:, None] + 2.0 + rng.normal(0, 5, (worlds, 4)) - 20.0 * (rng.random((worlds, 1)) < 0.1)
        found = diff.paired_difference(a, b)
        return found["low"], found["high"]

    # P(A fails) = 0.1, P(B fails) = 0.15, outcomes correlated through the world
    cells = np.array([0.82, 0.03, 0.08, 0.07])  # (pass, pass), (pass, fail) ... as (A, B)

    def failures(rng):
        kind = rng.choice(4, worlds, p=cells)
        fail_a, fail_b = kind >= 2, kind % 2 == 1
        found = diff.paired_failures(fail_a, fail_b)["difference"]
        return found["low"], found["high"]

    assert coverage(returns, 2.0 - 20.0 * 0.1, 400, seed=0) >= 0.93
    assert coverage(failures, (cells[1] + cells[3]) - (cells[2] + cells[3]), 400, seed=1) >= 0.93
