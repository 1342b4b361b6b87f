"""Explanations: the failing/passing boundary on a toy, nearest passing worlds, failure clusters."""

from __future__ import annotations

import numpy as np
import pytest

from worldagent.analysis.explanations import boundary, clusters, nearest
from worldagent.errors import WorldagentError


def test_the_boundary_brackets_a_toy_threshold_and_counts_its_evaluations():
    calls = []

    def fails(z):  # a world fails while its first coordinate is below 0.3
        calls.append(len(z))
        return z[:, 0] < 0.3

    z_fail, z_pass = np.array([-1.0, 2.0]), np.array([1.0, 2.0])
    found = boundary(fails, z_fail, z_pass, rounds=3, points=7)
    assert found.failing[0] < 0.3 <= found.passing[0]
    assert found.passing[0] - found.failing[0] == pytest.approx(2.0 / 8**3)  # the bracket shrinks 8× per round
    assert found.evaluated == sum(calls) == 21 and found.failing[1] == found.passing[1] == 2.0
    assert 0.0 <= found.t_failing < found.t_passing <= 1.0


def test_a_segment_that_passes_at_once_keeps_the_failing_end():
    found = boundary(lambda z: np.zeros(len(z), bool), np.zeros(3), np.ones(3), rounds=2, points=3)
    assert found.t_failing == 0.0 and found.t_passing == pytest.approx(1 / 16)
    with pytest.raises(WorldagentError, match="at least 1"):
        boundary(lambda z: z[:, 0] > 0, np.zeros(3), np.ones(3), rounds=0)


def test_the_nearest_passing_world_and_none_to_compare_with():
    assert nearest(np.array([0.0, 0.0]), np.array([[3.0, 0.0], [0.5, 0.5], [-1.0, 0.0]])) == 1
    with pytest.raises(WorldagentError, match="no passing world"):
        nearest(np.zeros(2), np.zeros((0, 2)))


def test_two_separate_groups_of_failures_are_found_with_central_representatives():
    rng = np.random.default_rng(0)
    measures = np.concatenate([rng.normal([0, 0], 0.1, (30, 2)), rng.normal([5, 5], 0.1, (10, 2))])
    latents = np.concatenate([rng.normal(-1, 0.1, (30, 4)), rng.normal(1, 0.1, (10, 4))])
    found = clusters(measures, latents, count=2)
    assert [len(c.members) for c in found] == [30, 10]
    assert found[0].representative < 30 <= found[1].representative
    np.testing.assert_allclose(found[1].centre, [5, 5], atol=0.1)
    assert clusters(np.zeros((0, 2)), np.zeros((0, 4))) == []
    assert len(clusters(np.ones((3, 2)), np.ones((3, 4)), count=4)) == 1  # identical worlds: one group
