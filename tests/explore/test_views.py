"""The pure functions behind the explorer's views: projection, prior likelihood, severity, nearest, atlas cells."""

from __future__ import annotations

import numpy as np
import pytest

from worldagent.events import parse_selection
from worldagent.explore import views


def test_the_projection_keeps_the_two_widest_directions():
    rng = np.random.default_rng(0)
    latents = rng.normal(size=(200, 4)) * np.array([5.0, 0.1, 2.0, 0.1])
    projection = views.principal_projection(latents)
    np.testing.assert_allclose(np.abs(projection.axes[0]), [1, 0, 0, 0], atol=0.05)
    np.testing.assert_allclose(np.abs(projection.axes[1]), [0, 0, 1, 0], atol=0.05)
    assert np.allclose(projection(latents), views.principal_projection(latents)(latents))  # deterministic signs
    assert views.principal_projection(latents[:1]).axes.shape == (2, 4)  # one world: still a 2-D view
    assert views.principal_projection(np.zeros((3, 1))).axes.shape == (2, 1)


def test_log_prior_is_the_standard_normal_density():
    z = np.array([[0.0, 0.0], [1.0, -2.0]])
    np.testing.assert_allclose(views.log_prior(z), [-np.log(2 * np.pi), -2.5 - np.log(2 * np.pi)])


def test_severity_is_the_distance_past_each_one_sided_threshold():
    means = {"crashed": np.array([0.9, 0.6, 0.2]), "return": np.array([-10.0, 5.0, 40.0])}
    assert views.severity(parse_selection("crash_rate > 0.5", "racing"), means) == pytest.approx([0.4, 0.1, -0.3])
    both = views.severity(parse_selection("crashed >= 0.5 and return < 0", "racing"), means)
    assert both == pytest.approx([0.4 + 10.0, 0.1 - 5.0, -0.3 - 40.0])


def test_failures_rank_likeliest_or_most_severe_first():
    latents = np.array([[3.0], [0.1], [1.0], [0.0]])
    failing = np.array([True, True, True, False])
    severities = np.array([5.0, 1.0, 2.0, 9.0])
    assert views.rank_failures(latents, failing, severities, "likelihood").tolist() == [1, 2, 0]
    assert views.rank_failures(latents, failing, severities, "severity").tolist() == [0, 2, 1]


def test_nearest_skips_the_same_latent():
    found, distance = views.nearest(np.array([[0.0, 0.0]]), np.array([[0.0, 0.0], [3.0, 4.0], [6.0, 8.0]]), beyond=1e-9)
    assert found.tolist() == [1] and distance.tolist() == [5.0]
    assert views.nearest(np.array([[0.0, 0.0]]), np.zeros((0, 2)))[0].tolist() == [-1]
    assert views.nearest(np.array([[0.0]]), np.array([[0.0]]), beyond=1e-9)[0].tolist() == [-1]


def test_atlas_cells_fold_extra_descriptors_into_the_worst_world():
    grid = (2, 2, 3)
    cells = np.ravel_multi_index(([0, 0, 1], [1, 1, 0], [0, 2, 1]), grid)
    scores = np.array([4.0, -1.0, 7.0])
    found = views.atlas_cells(cells, grid, scores, maximize=False)
    assert found == [{"x": 0, "y": 1, "score": -1.0, "entry": 1}, {"x": 1, "y": 0, "score": 7.0, "entry": 2}]
    best = views.atlas_cells(cells, grid, scores, maximize=True)
    assert best[0] == {"x": 0, "y": 1, "score": 4.0, "entry": 0}


def test_a_world_evaluated_again_is_one_world():
    first, counts = views.distinct_worlds(["a", "b", "a", "a"], np.array([2, 1, 0, 3]))
    assert first.tolist() == [2, 1] and counts.tolist() == [3, 1]


def test_each_campaign_has_its_own_marker_up_to_the_distinct_count():
    markers = views.campaign_markers(12)  # the quick run's twelve campaigns: two shared a shape before
    assert len({(m["shape"], m["filled"]) for m in markers}) == 12
    assert len({(m["shape"], m["filled"]) for m in views.MARKERS}) == len(views.MARKERS) == 22
    every = views.campaign_markers(len(views.MARKERS) + 2)
    assert len({(m["shape"], m["filled"]) for m in every[: len(views.MARKERS)]}) == len(views.MARKERS)
    # past the distinct count markers start over (the map's legend says so): campaign 23 looks like campaign 1
    assert every[len(views.MARKERS)] == every[0] and every[len(views.MARKERS) + 1] == every[1]


def test_the_worse_end_of_a_metric_is_the_failure_side_then_the_atlas_side():
    selection = parse_selection("crashed > 0.5", "racing")
    names = ["return", "crashed", "steps"]
    # the failure event's side first; an atlas minimising return searched its low end; steps: nobody says
    assert views.worse_ends(selection, [("return", False), ("crashed", False)], names) == {"crashed": "high", "return": "low"}
    assert views.worse_ends(parse_selection("group_reward < 50", "harvest"), [("group_reward", True)], ["group_reward"]) == {"group_reward": "low"}
    assert views.worse_ends(None, [("return", True), ("other", False)], names) == {"return": "high"}  # only metrics the map has
