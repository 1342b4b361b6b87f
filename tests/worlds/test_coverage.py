"""G(z) against fresh procedural worlds (issue 48): the two papers' estimators, fresh seeds, the uncovered warning."""

from __future__ import annotations

import numpy as np
import pytest

from scatter_env import registered
from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.worlds.coverage import (
    FeatureSpace,
    coverage,
    density_coverage,
    descriptor_quantiles,
    fresh_seeds,
    fresh_worlds,
    parameter_spread,
    precision_recall,
)
from worldagent.worlds.dataset import make_dataset
from worldagent.worlds.quality import MIN_COVERED_SHARE, _uncovered

MODES = 10


def modes(count: int, which, seed: int) -> np.ndarray:
    """f[count, 2]: points of tight Gaussian modes 10 apart on a line, drawn evenly from the modes ``which``."""
    rng = np.random.default_rng(seed)
    centres = np.stack([10.0 * np.asarray(which)[rng.integers(0, len(which), count)], np.zeros(count)], axis=1)
    return centres + rng.normal(size=(count, 2))


def test_identical_distributions_score_near_one():
    real, fake = modes(600, range(MODES), 0), modes(600, range(MODES), 1)
    scores = {**precision_recall(real, fake), **density_coverage(real, fake)}
    assert scores["precision"] > 0.9 and scores["recall"] > 0.9
    assert 0.8 < scores["density"] < 1.2
    assert scores["coverage"] == pytest.approx(1 - 2**-5, abs=0.04)  # Naeem et al.: 1 - 2^-k for equal-size samples


def test_disjoint_distributions_score_zero():
    real, fake = modes(300, range(MODES), 0), modes(300, range(MODES), 1) + [0.0, 1000.0]
    assert precision_recall(real, fake) == {"precision": 0.0, "recall": 0.0}
    assert density_coverage(real, fake) == {"density": 0.0, "coverage": 0.0}


def test_a_generator_covering_half_the_modes_covers_half():
    real, fake = modes(1000, range(MODES), 0), modes(1000, range(0, MODES, 2), 1)
    scores = {**precision_recall(real, fake), **density_coverage(real, fake)}
    assert scores["coverage"] == pytest.approx(0.5, abs=0.06) and scores["recall"] == pytest.approx(0.5, abs=0.06)
    assert scores["precision"] > 0.9  # what it makes lies where the real points are
    assert scores["density"] == pytest.approx(1.0, abs=0.2)  # as real-looking as real points: density measures fidelity, not spread


def test_duplicates_count_as_inside_and_too_few_points_are_refused():
    points = np.repeat(np.arange(4.0)[:, None], 6, axis=0)  # each point 6 times: every k-th neighbour is a copy
    assert density_coverage(points, points) == {"density": 6 / 5, "coverage": 1.0}
    with pytest.raises(WorldagentError, match="at least 6"):
        precision_recall(points[:5], points)


def test_fresh_seeds_lie_past_every_dataset_seed_and_the_floor_range_past_them():
    assert fresh_seeds(np.array([3, 9, 5]), 4).tolist() == [10, 11, 12, 13]
    assert fresh_seeds(np.array([3, 9, 5]), 4, offset=4).tolist() == [14, 15, 16, 17]
    with registered() as spec:
        dataset = make_dataset(spec.name, 40, 7, progress=False)
        fresh = fresh_worlds(spec, dataset, 30)
    assert fresh.seeds.min() > dataset.seeds.max() and len(fresh) == 30


def test_the_feature_space_standardises_descriptors_and_drops_constant_ones():
    rng = np.random.default_rng(0)
    cells = (rng.random((200, 30)) < 0.3).astype(np.uint8)
    described = {"varied": rng.normal(5.0, 2.0, 200), "constant": np.ones(200)}
    space = FeatureSpace.fit(described, cells, dims=4)
    features = space(described, cells)
    assert space.names == ("varied",) and features.shape == (200, 1 + 4)
    assert features[:, 0].mean() == pytest.approx(0.0, abs=1e-9) and features[:, 0].std() == pytest.approx(1.0)
    assert (features[:, 1:] ** 2).sum(axis=1).mean() == pytest.approx(1.0)  # the embedding weighs as much as the one descriptor
    assert (FeatureSpace.fit({}, cells, dims=4)({}, cells) ** 2).sum(axis=1).mean() == pytest.approx(4.0)  # no descriptors: 1 per dimension
    assert np.var(features[:, 1]) >= np.var(features[:, 4])  # components keep their order of variance (not whitened)


def test_an_embedding_fitted_on_other_worlds_scores_two_samples_of_noise_alike():
    """Principal directions fitted on the reference worlds themselves fit their noise and spread them wider than any other sample."""
    rng = np.random.default_rng(0)
    real, fake, other = ((rng.random((200, 300)) < 0.1).astype(np.uint8) for _ in range(3))
    fair = FeatureSpace.fit({}, real, basis=other)
    scores = {**precision_recall(fair({}, real), fair({}, fake)), **density_coverage(fair({}, real), fair({}, fake))}
    assert scores["recall"] > 0.85 and scores["density"] == pytest.approx(1.0, abs=0.15)
    own = FeatureSpace.fit({}, real)
    assert precision_recall(own({}, real), own({}, fake))["recall"] < 0.5


def test_principal_directions_from_the_gram_matrix_are_the_svds():
    from worldagent.worlds.coverage import _principal_directions

    rows = np.random.default_rng(1).normal(size=(50, 80)) * np.linspace(3.0, 0.1, 80)
    rows -= rows.mean(axis=0)
    directions, explained = _principal_directions(rows, 4)
    _, singular, expected = np.linalg.svd(rows, full_matrices=False)
    np.testing.assert_allclose(np.abs(directions @ expected[:4].T), np.eye(4), atol=1e-8)  # the same axes, up to sign
    assert explained == pytest.approx((singular[:4] ** 2).sum() / (singular**2).sum())


def test_quantiles_and_parameter_spread_side_by_side():
    values = np.arange(101.0)
    table = descriptor_quantiles({"generator": {"d": values / 2}, "fresh": {"d": values}})
    assert table == {"d": {"generator": [2.5, 12.5, 25.0, 37.5, 47.5], "fresh": [5.0, 25.0, 50.0, 75.0, 95.0]}}
    spread = parameter_spread({"a": values / 4, "b": values}, {"a": values, "b": values})
    assert spread["parameters"]["a"]["std_ratio"] == pytest.approx(0.25) and spread["min_std_ratio"] == pytest.approx(0.25)
    assert spread["median_std_ratio"] == pytest.approx(0.625)


@pytest.fixture(scope="module")
def scatter_sides():
    """(spec, dataset, faithful worlds, narrowed worlds), 128 each: the scatter generator at other seeds, and only its mazes of 0-5 walls."""
    with registered() as spec:
        dataset = make_dataset(spec.name, 128, 0, progress=False)
        faithful = make_dataset(spec.name, 128, 50_000, progress=False)
        pool = make_dataset(spec.name, 1024, 60_000, progress=False)
        few = np.flatnonzero(np.asarray(pool.cells[:, : 13 * 13]).sum(axis=1) <= 5)[:128]  # a quarter of U{0..25} walls
        yield spec, dataset, faithful.worlds, pool.subset(few).worlds


def test_the_uncovered_warning_fires_on_a_narrowed_generator_only(scatter_sides):
    spec, dataset, faithful, narrowed = scatter_sides
    with registered():
        fair = coverage(spec, faithful, 128, dataset)
        narrow = coverage(spec, narrowed, 128, dataset)
    assert fair["coverage"] > 0.8 and _uncovered(fair) == []
    assert narrow["coverage"] < MIN_COVERED_SHARE * narrow["floor"]["coverage"]
    (line,) = _uncovered(narrow)
    assert line.startswith("uncovered: ") and "--repair" in line
    assert fair["fresh_seeds"][0] > dataset.seeds.max() and fair["generator_params"] is None  # scatter declares none
    assert set(fair["quantiles"]) == {"wall_count", "goal_distance"}
    walls = narrow["quantiles"]["wall_count"]
    assert walls["generator"][-1] <= 5 < walls["fresh"][-1]


def test_racing_reads_its_checkpoint_draws_back_off_its_tracks(racing_data):
    """Named in the walker's order: the read radii follow the drawn ones (angles too, less closely)."""
    from worldagent.envs.racing import walker
    from worldagent.envs.racing.open_repair import to_unit

    read = registry.get("racing").generator_params(racing_data.worlds)
    rngs = [np.random.Generator(np.random.PCG64(np.random.SeedSequence(int(s)))) for s in racing_data.seeds]
    noise, rad = walker.draws(rngs)
    drawn = np.asarray(to_unit(noise, rad))  # the first set of draws; upstream redraws ~6% of them (noise here)
    assert list(read) == [f"angle_{k}" for k in range(1, 11)] + [f"radius_{k}" for k in range(1, 11)]
    values = np.stack(list(read.values()), axis=1)
    assert values.min() >= 0.0 and values.max() <= 1.0
    correlation = [np.corrcoef(values[:, i], drawn[:, i])[0, 1] for i in range(20)]
    assert np.mean(correlation[10:]) > 0.7 and np.mean(correlation[:10]) > 0.3
