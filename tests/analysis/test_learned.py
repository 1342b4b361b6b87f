"""The learned proposal (``analysis.learned``): on worlds that repeat (tracks), whose failures no descriptor predicts, its
rounds find the failing worlds the descriptor-only surrogate cannot, and its estimate stays unbiased with intervals that
hold."""

from __future__ import annotations

import numpy as np
from scipy.stats import norm

from worldagent.analysis import failure_rate as fr
from worldagent.analysis import learned, pooled, surrogate

CELLS = 300  # distinct worlds (tracks); a latent's world is set by its first coordinate
PLACES = np.random.default_rng(11).standard_normal((CELLS, 2))  # their descriptors, unrelated to which fail
FAILING = np.random.default_rng(12).choice(CELLS, 6, replace=False)
MEANS = np.where(np.isin(np.arange(CELLS), FAILING), -1.0, -4.5)  # a world's mean margin; each play adds N(0, 1)
TRUTH = float(np.mean(norm.sf(-MEANS)))  # ≈ 3.2e-3


def cell(z: np.ndarray) -> np.ndarray:
    return np.minimum((norm.cdf(z[:, 0]) * CELLS).astype(int), CELLS - 1)


def describe(z: np.ndarray) -> np.ndarray:
    return PLACES[cell(z)]


def play(z: np.ndarray, seeds: np.ndarray) -> fr.Scored:
    """Each world played afresh: its track's mean margin plus noise from the campaign's seeds."""
    margin = MEANS[cell(z)] + np.random.default_rng(np.asarray(seeds, np.uint64).tolist()).standard_normal(len(z))
    return fr.Scored(margin, margin > 0, len(z))


def failing_share(strata: pooled.Strata, labels: np.ndarray) -> float:
    """The expected share of the draws that land on a failing track under the strata's allocation."""
    on_failing = np.bincount(strata.labels, weights=np.isin(labels, FAILING)) / np.bincount(strata.labels)
    return float(pooled.allocation(strata) @ on_failing)


def test_the_rounds_put_more_draws_on_failing_worlds_than_the_descriptors_alone():
    rng = np.random.default_rng(0)
    z = rng.standard_normal((20_000, 3))
    tracks, described = cell(z), describe(z)
    features = surrogate.features(z, described)
    pilot = play(z[:300], np.arange(300))
    spend = fr.Spender(play, 0)
    model, probability = learned.learn(spend, rng, z, features, learned.cells(described, len(z)), pilot.margin, pilot.event, 1000)
    assert spend.worlds == learned.STAGES * 300
    descriptors_only = pooled.stratify(surrogate.log_chances(features, features[:300], pilot.margin))
    taught = model.strata(probability)
    prior_share = len(FAILING) / CELLS
    assert failing_share(taught, tracks) > max(5 * failing_share(descriptors_only, tracks), 10 * prior_share), (
        failing_share(taught, tracks),
        failing_share(descriptors_only, tracks),
    )


def test_the_learned_estimate_is_unbiased_and_its_intervals_hold(monkeypatch):
    monkeypatch.setattr(pooled, "MIN_GAIN", 0.0)  # the learned path on every seed, whatever the pilot or plan predicts
    monkeypatch.setattr(learned, "LEARN_GATE", 0.0)
    config = fr.ImportanceConfig(proposal="learned", pool=20_000, pilot=300)
    found = [fr.importance_sampling(play, 3, 3000, config=config, seed=seed, describe=describe) for seed in range(12)]
    assert all(e.method == "is" and e.search_worlds == 300 * (1 + learned.STAGES) for e in found)
    covered = np.mean([e.low <= TRUTH <= e.high for e in found])
    mean = np.mean([e.estimate for e in found]) / TRUTH
    assert covered >= 11 / 12 and 0.85 < mean < 1.15, (covered, mean)
