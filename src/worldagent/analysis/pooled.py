"""Importance sampling over a described pool of prior worlds, stratified by a surrogate's chances (``failure_rate``).

1. *Pool*: M latents z ~ N(0, I) from their own stream (a prefix of it: the same seed gives the
   same first rows at any M, so a described pool serves every event and every smaller M). A
   timed sample of the pool is described first; the rest only when the plan says it pays.
2. *Pilot*: the pool's first ``pilot`` worlds are played; a ridge regression of their margins
   (``analysis.surrogate``) gives every pool world a modelled chance c_j of the event.
3. *Strata*: the pool sorted by c_j and cut where the modelled event mass reaches 50, 80, 95
   and 99% (``STRATUM_EDGES``); stratum h holds a known share a_h of the pool.
4. *Plan*: draws per stratum by Neyman's allocation on the modelled chances, with a quarter of
   the event's mass (``DEFENSIVE``) assumed anywhere in the pool. From it, the draws a target
   width needs and the gain over Monte Carlo, in episodes and in seconds (describing the pool
   included). Below ``MIN_GAIN`` the estimator falls back to Monte Carlo.
5. *Estimate*: P = Σ_h a_h · hits_h / n_h, each stratum drawn without replacement (with, if it
   is smaller than its draws); the interval is ``gamma_interval`` on those weighted hits with
   the pool's own binomial variance P(1 − P)/M, taken on the complement when P > 1/2.

Why strata rather than a defensive mixture q = α/M + (1 − α) c/Σc: with a trained racing agent
the surrogate put ~90% of q on 3–4% of the pool, and 12–14% of P lay in worlds drawn at the
prior's share α = 0.1, about 0.2 times in a run of 10,000. A run usually missed that mass (low
estimates), the normal interval never saw it, and one draw there added ~P at once (weight 10).
Strata sample the pool's bulk at a rate set by the mass it may hold, the estimate is a convex
combination of hit fractions (so it stays in [0, 1]), and the interval's upper bound counts one
more hit at the largest stratum weight, so a stratum with no hit yet still widens it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from statistics import NormalDist

import numpy as np

from worldagent.analysis import surrogate
from worldagent.analysis.intervals import bounded, gamma_interval

STRATUM_EDGES = (0.5, 0.8, 0.95, 0.99)  # cumulative modelled event mass at which the sorted pool is cut
UNSEEN = False  # the interval's upper bound adds a hit at the largest weight of any stratum (True) or of one with hits
DEFENSIVE = 0.1  # share of the event's mass the allocation assumes may lie anywhere in the pool (the model's misses)
MIN_DRAWS = 2  # per stratum: each stratum is seen
MIN_GAIN = 1.5  # predicted gain over Monte Carlo below which the estimator falls back to it
TIMED_SAMPLE = 2000  # pool worlds described first: the surrogate's scaling, and the per-world cost of describing
DEFAULT_POOL = 200_000  # the pool at most when it adapts to a time budget
MAX_POOL = 5_000_000  # a pool larger than this is refused (memory: M x latent dim x 8 bytes, twice)
POOL_SECONDS = 120.0  # default time budget for describing the pool


@dataclass(frozen=True)
class Strata:
    """The pool cut by modelled chance.

    Attributes:
        labels: int[M] each pool world's stratum (0: the likeliest).
        masses: f64[S] each stratum's share of the pool, a_h.
        modelled: f64[S] its mean modelled chance of the event.
        shares: f64[S] the draws' shares per stratum when another model than ``modelled`` set them (None: Neyman's on
            ``modelled``, ``allocation``).
    """

    labels: np.ndarray
    masses: np.ndarray
    modelled: np.ndarray
    shares: np.ndarray | None = None

    @property
    def probability(self) -> float:
        """The model's P: Σ a_h · modelled_h."""
        return float(self.masses @ self.modelled)


@dataclass(frozen=True)
class Plan:
    """What the pilot predicts, decided before the pool is described in full.

    Attributes:
        pool: M, the pool's worlds.
        draws: worlds to sample from the strata after the pilot.
        modelled_probability: the model's P.
        predicted_width: the interval's relative half-width ``draws`` should give.
        mc_worlds: worlds Monte Carlo needs for that width at the model's P.
        gain_episodes, gain_seconds: Monte Carlo's cost over this estimator's (pilot and describing included).
        episode_seconds, describe_seconds: per world, measured (or replayed).
        describe_total: seconds predicted to describe the rest of the pool.
        fallback: why Monte Carlo runs instead, or None.
    """

    pool: int
    draws: int
    modelled_probability: float
    predicted_width: float
    mc_worlds: float
    gain_episodes: float
    gain_seconds: float
    episode_seconds: float
    describe_seconds: float
    describe_total: float
    fallback: str | None = None

    def as_dict(self) -> dict:
        return asdict(self)


def stratify(log_chance: np.ndarray, edges: tuple[float, ...] = STRATUM_EDGES) -> Strata:
    """``Strata`` of a pool from its worlds' log chances f64[M]: cut where the sorted modelled mass reaches ``edges``."""
    log_chance = np.asarray(log_chance, np.float64)
    size = len(log_chance)
    order = np.argsort(-log_chance, kind="stable")
    chance = np.exp(log_chance)
    total = chance.sum()
    cuts = np.searchsorted(np.cumsum(chance[order]) / total, edges) + 1 if total > 0 else np.array([], int)
    bounds = np.unique(np.concatenate([[0], np.clip(cuts, 1, size), [size]]))
    labels = np.empty(size, int)
    for h, (start, stop) in enumerate(zip(bounds[:-1], bounds[1:])):
        labels[order[start:stop]] = h
    counts = np.bincount(labels)
    return Strata(labels, counts / size, np.bincount(labels, weights=chance) / counts)


def allocation(strata: Strata, defensive: float | None = None) -> np.ndarray:
    """f64[S] shares of the draws per stratum: Neyman's, a_h · sqrt(p_h (1 − p_h)), on the modelled chances with
    ``defensive`` of the mass spread over the whole pool (``strata.shares`` when they are set)."""
    if strata.shares is not None:
        return strata.shares
    assumed = assumed_chances(strata, defensive)
    spread = strata.masses * np.sqrt(assumed * (1 - assumed))
    return spread / spread.sum() if spread.sum() > 0 else strata.masses


def assumed_chances(strata: Strata, defensive: float | None = None) -> np.ndarray:
    """f64[S]: the chance the plan assumes per stratum, (1 − defensive) · modelled + defensive · P_model."""
    defensive = DEFENSIVE if defensive is None else defensive
    return (1 - defensive) * strata.modelled + defensive * strata.probability


def draws_per_stratum(draws: int, shares: np.ndarray) -> np.ndarray:
    """int[S]: ``draws`` split by ``shares`` (largest remainders), each stratum at least ``MIN_DRAWS``."""
    exact = draws * np.asarray(shares, np.float64)
    counts = np.floor(exact).astype(int)
    counts[np.argsort(counts - exact)[: draws - counts.sum()]] += 1
    return np.maximum(counts, MIN_DRAWS)


def predicted_width(strata: Strata, draws: int, pool: int, defensive: float | None = None, confidence: float = 0.95) -> float:
    """The relative half-width ``stratified_estimate``'s interval should have after ``draws`` draws: its interval at the
    expected hits under the assumed chances (inf when the model's P is 0)."""
    probability = strata.probability
    if probability <= 0:
        return float("inf")
    counts = draws_per_stratum(draws, allocation(strata, defensive))
    expected = counts * assumed_chances(strata, defensive)
    low, high = _interval(strata.masses / counts, expected, counts, probability, pool, confidence, seen=expected >= 1)
    return (high - low) / (2 * probability)


def draws_for_width(strata: Strata, pool: int, width: float, most: int, defensive: float | None = None, confidence: float = 0.95) -> int | None:
    """The fewest draws (at most ``most``) whose ``predicted_width`` is within ``width``; None when even ``most`` is not."""
    if predicted_width(strata, most, pool, defensive, confidence) > width:
        return None
    low, high = MIN_DRAWS * len(strata.masses), most
    while low < high:  # the predicted width falls as draws grow
        middle = (low + high) // 2
        low, high = (middle + 1, high) if predicted_width(strata, middle, pool, defensive, confidence) > width else (low, middle)
    return low


def monte_carlo_worlds(probability: float, width: float, confidence: float = 0.95) -> float:
    """Worlds Monte Carlo needs for ±width · P, by the binomial's normal approximation z² (1 − P) / (P width²) (inf
    when P is 0). At rare P it is 15.4 / P for ±50%, a little under the 18 / P its stopping rule spends: the gain it
    gives is not overstated."""
    z = NormalDist().inv_cdf(1 - (1 - confidence) / 2)
    return max(1.0, z**2 * (1 - probability) / (probability * width**2)) if probability > 0 and width > 0 else float("inf")


def pool_size(configured: int | None, budget_seconds: float, describe_seconds: float, sample: int) -> int:
    """M: ``configured``, or as many worlds as ``budget_seconds`` of describing buys (``describe_seconds`` per world),
    at most ``DEFAULT_POOL`` and at least the timed sample."""
    if configured is not None:
        return int(configured)
    affordable = DEFAULT_POOL if describe_seconds <= 0 else int(budget_seconds / describe_seconds)
    return int(min(DEFAULT_POOL, max(sample, affordable)))


def plan(
    strata: Strata, pool: int, pilot: int, worlds: int, target_width: float | None, episode_seconds: float, describe_seconds: float,
    described: int, confidence: float = 0.95, source: str = "the pilot's model", met: int | None = None,
) -> Plan:  # fmt: skip
    """The draws, and the gain over Monte Carlo at the width they reach, with the fallback's reason when it is below
    ``MIN_GAIN`` (in episodes, or in seconds where the pool's describing is measured).

    Args:
        strata: of the timed sample (its shares stand for the pool's).
        pool: M; pilot: worlds already played; worlds: draws at most; described: pool worlds already described.
        source: what the strata come from, in the fallback's reason.
        met: pilot worlds that met the event (None: not known); with none, the fallback says so and what to change.
        episode_seconds, describe_seconds: per world.
    """
    probability = strata.probability
    needed = None if target_width is None else draws_for_width(strata, pool, target_width, worlds, confidence=confidence)
    draws = max(worlds if needed is None else needed, MIN_DRAWS * len(strata.masses))
    width = predicted_width(strata, draws, pool, confidence=confidence)
    mc = monte_carlo_worlds(probability, width if target_width is None else max(width, target_width), confidence)
    describe_total = describe_seconds * max(pool - described, 0)
    gain_episodes = mc / (pilot + draws)
    spent = (pilot + draws) * episode_seconds + describe_total
    gain_seconds = mc * episode_seconds / spent if spent > 0 else gain_episodes
    fallback = None
    if MIN_GAIN > 0 and not width <= 1 and met == 0:
        # with no hit the model's P is its smoothing alone, and the width predicted from it means nothing
        fallback = (
            f"no pilot world met the event (0 of {pilot:,}), so {source} cannot place the event; "
            "a larger --pilot, or a laxer event (e.g. a lower threshold), gives it hits to learn from"
        )
    elif MIN_GAIN > 0 and not width <= 1:
        fallback = f"{source} cannot place the event ({width_text(width)} predicted after {draws:,} draws)"
    elif min(gain_episodes, gain_seconds) < MIN_GAIN:
        what, gain = ("in episodes", gain_episodes) if gain_episodes < MIN_GAIN else ("in seconds, describing the pool included", gain_seconds)
        fallback = f"importance sampling is predicted to gain {gain:.2g}x over Monte Carlo {what} (below {MIN_GAIN}x)"
    return Plan(
        pool, draws, probability, width, mc, gain_episodes, gain_seconds, episode_seconds, describe_seconds, describe_total, fallback
    )  # fmt: skip


def width_text(width: float) -> str:
    """``±240%``; a width past ±1,000% (a model that barely saw the event) as ``over ±1,000%``."""
    return f"±{width:.0%}" if width <= 10 else "over ±1,000%"


def stratified_estimate(
    hits: np.ndarray, draws: np.ndarray, masses: np.ndarray, pool: int, confidence: float = 0.95
) -> tuple[float, float, float, float]:
    """(P, low, high, event ESS) from hits int[S] in draws int[S] per stratum of masses f64[S] in a pool of M worlds.

    P = Σ a_h hits_h / n_h; the interval is ``gamma_interval`` on the weighted hits (weights a_h / n_h) with the pool's
    binomial variance, on the misses instead when P > 1/2 (both are sums of counts; the rarer is the one to bound).
    The event ESS is P² / Σ (a_h / n_h)² hits_h: how many equally weighted hits the estimate is worth.
    """
    weights = np.asarray(masses, np.float64) / np.asarray(draws, np.float64)
    hits = np.asarray(hits, np.float64)
    estimate = float(weights @ hits)
    low, high = _interval(weights, hits, np.asarray(draws, np.float64), estimate, pool, confidence)
    squares = float(weights**2 @ hits)
    return (*bounded(estimate, low, high), estimate**2 / squares if squares > 0 else 0.0)


def _interval(
    weights: np.ndarray, hits: np.ndarray, draws: np.ndarray, estimate: float, pool: int, confidence: float, seen: np.ndarray | None = None
) -> tuple[float, float]:
    """``gamma_interval`` on the weighted hits f64[S] with the pool's binomial variance; on the misses when P > 1/2
    (``seen``: strata taken as hit, for a prediction from expected hits)."""
    pool_variance = estimate * (1 - estimate) / pool
    if estimate <= 0.5:
        return gamma_interval(weights, hits, confidence, pool_variance, UNSEEN, seen)
    misses = draws - hits
    miss_low, miss_high = gamma_interval(weights, misses, confidence, pool_variance, UNSEEN, None if seen is None else misses >= 1)
    return 1 - miss_high, 1 - miss_low


def stratified_draws(rng: np.random.Generator, strata: Strata, counts: np.ndarray) -> np.ndarray:
    """int[Σ counts]: pool indices, ``counts[h]`` from stratum h, without replacement where the stratum is large enough."""
    picked = []
    for h, count in enumerate(counts):
        members = np.flatnonzero(strata.labels == h)
        picked.append(rng.choice(members, size=int(count), replace=bool(count > len(members))))
    return np.concatenate(picked)


class Clock:
    """Seconds spent in calls, per world: ``timed(f, n)(*args)`` runs f and adds its wall time for n worlds."""

    def __init__(self):
        self.seconds, self.worlds = 0.0, 0

    def timed(self, function: Callable, worlds: int) -> Callable:
        def call(*args, **kwargs):
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                self.seconds += time.perf_counter() - start
                self.worlds += worlds

        return call

    @property
    def per_world(self) -> float:
        return self.seconds / self.worlds if self.worlds else 0.0


def pool_chances(pool: np.ndarray, described: np.ndarray | None, sample: int, pilot_margins: np.ndarray) -> np.ndarray:
    """f64[len(pool)] log chances: the surrogate fitted on the pool's first len(pilot_margins) worlds, descriptors scaled as in its first ``sample``."""
    features = surrogate.features(pool, described, reference=sample)
    return surrogate.log_chances(features, features[: len(pilot_margins)], pilot_margins)
