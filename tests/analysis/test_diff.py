"""Pooled, paired comparison of two arms of trained agents (``analysis.diff.pooled_difference``)."""

from __future__ import annotations

import numpy as np
import pytest

from worldagent.analysis.diff import cvar, pooled_difference

MEAN = lambda values: float(values.mean())  # noqa: E731


def arms(shift: float, world_spread: float = 10.0, seeds: int = 5, worlds: int = 400):
    """(arm, base) f[S, W]: shared world effects of spread ``world_spread``, small seed and episode noise, the arm ``shift`` higher."""
    rng = np.random.default_rng(0)
    world = rng.normal(0, world_spread, worlds)
    base = world + rng.normal(0, 0.3, (seeds, 1)) + rng.normal(0, 0.5, (seeds, worlds))
    arm = world + shift + rng.normal(0, 0.3, (seeds, 1)) + rng.normal(0, 0.5, (seeds, worlds))
    return arm, base


def test_a_shift_hidden_by_world_spread_is_found_because_worlds_are_paired():
    arm, base = arms(0.8)
    found = pooled_difference(arm, base, MEAN, resamples=400)
    assert found["low"] > 0 and abs(found["difference"] - 0.8) < 0.4
    unpaired = 1.96 * np.hypot(arm.mean(0).std() / np.sqrt(400), base.mean(0).std() / np.sqrt(400))
    assert unpaired > found["difference"]  # worlds resampled apart, the same shift would not be told from 0


def test_equal_arms_differ_by_zero_with_an_interval_around_it():
    arm, _ = arms(0.0)
    found = pooled_difference(arm, arm, lambda v: float(cvar(v, 0.1, axis=1).mean()), resamples=300)
    assert found["difference"] == 0 and found["low"] < 0 < found["high"]
    assert found["seeds"] == [5, 5] and found["worlds"] == 400


def test_mismatched_worlds_are_refused():
    with pytest.raises(ValueError, match="same W worlds"):
        pooled_difference(np.zeros((3, 10)), np.zeros((3, 11)), MEAN)
