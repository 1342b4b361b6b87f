"""The probability of a failure under the world distribution (DESIGN.md "Failure probability").

An event (a selection such as ``crash_rate > 0.5``, per-world means over its episodes) has a
probability P under the generator's prior: worlds G(z), z ~ N(0, I). Two estimators, both
pure functions of an ``evaluate(z f64[n, dim], seeds int[n]) -> Scored`` callable, so that a
closed-form toy (event ``z[0] > 3``) tests them without any environment:

- ``monte_carlo``: z ~ N(0, I); k of n worlds in the event; P = k / n with the exact binomial
  (Clopper–Pearson) interval, or, sampled to a target width, stopped at a fixed k-th hit with
  that rule's exact interval (inverse binomial sampling). Honest at any P, but a rare event
  needs ~ 4 / (P r²) worlds for a 95% interval of ±r·P.
- ``importance_sampling``: batches from a proposal q mixed with the prior, α N(0, I) + (1 − α) g,
  so that every weight p/q ≤ 1/α; P = mean(w · 1[event]). The proposal g is one of two
  (``ImportanceConfig.proposal``):

  - ``surrogate`` (the default; ``surrogate_sampling``, ``analysis.surrogate``): a pool of
    prior worlds is decoded and described (no episode); a pilot of them is played and a model
    of the event's margin from the worlds' descriptors weights the pool. On racing it reached
    Monte Carlo's width with 23x fewer episodes at p ~ 1e-3 and 145x at 1e-4, where the search
    below reached 3.3x and 14.5x: the search must find an event's cells in latent space one by
    one, while the descriptors see all of them at once. On harvest, 12x and 22x, once its
    descriptors said how far the spawns walk to the apples (docs/failure-rate.md).
  - ``search``, in two stages:

  1. *Search*: the cross-entropy method (Rubinstein & Kroese) learns a mixture of shifted priors
     Σ_k π_k N(c_k, I). Each round samples worlds, ranks them by the event's *margin* (how far
     past its thresholds a world is; > 0 inside), lowers the bar to the top ``elite_fraction``
     (never past the event itself), and fits the mixture to the elites weighted by p/q: the
     cross-entropy update in this family is weighted EM, run for 1 to ``components``
     components and kept at the lowest BIC.
  2. *Sampling*, in batches from the defensive mixture q = α N(0, I) + (1 − α) g, which keeps
     every weight w = p/q ≤ 1/α; P = mean(w · 1[event]) over all batches. Before each batch, g
     is refitted: ``wide_share`` of the search's mixture plus N(z_i, h² I) kernels (h =
     ``bandwidth``) around every event world z_i found so far, shares ∝ its weight: a kernel
     estimate of the prior on the event that grows as regions are found. Each batch is unbiased
     given the ones before, so the mean is unbiased; its interval treats the terms as
     independent. The search's worlds are spent, counted, and not in the mean.

  Why a mixture: an event is often several regions far apart in latent space (distinct tracks
  or maps). A single mean shift moves toward one of them, or toward their average where none
  lies, and leaves the others to the prior's share α: on the toy |z0| > 3.2 its interval covered
  P in 9 of 20 seeds, the mixture's in 20 of 20 (``tests``). Why kernels after the search: a
  generator that repairs to its dataset's worlds makes the event a union of small cells (one per
  track, per-coordinate spread ~0.5), where a shifted prior of scale 1 puts a few percent of its
  draws; kernels of bandwidth 0.7 around the hits put most of them there (racing, p ≈ 1e-4: 7-15x
  fewer worlds than Monte Carlo instead of 3-4x; benchmarks/results/failure-rate.json,
  docs/failure-rate.md). Why not narrower, or fitted, scales: in 10 dimensions a component
  narrower than the event's extent makes log-weights vary like a χ² sum over the coordinates;
  components with fitted scales (floor 0.3-0.5) locked onto one or two cells and their intervals
  missed P by 2-20x; a fitted diagonal scale covered 1 − Φ(3) on the toy z0 > 3 in ~55% of 40
  seeds against 97% for the shifted prior.

The estimator's g-th call of ``evaluate`` is generation g, its worlds played with
``evaluation_seed(seed, g, slot)`` as in a campaign. ``StoredEvaluate`` makes ``evaluate`` from
an agent's evaluator and a run store: each estimate is one store campaign (``campaign_name``)
whose generations are those calls (for importance sampling, the search's rounds first). A rerun
replays the stored generations (their latents must match) and evaluates only what is missing,
so a killed run loses nothing. One campaign per estimate, rather than one per search round,
keeps the store's campaigns readable and resuming a single lookup.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from statistics import NormalDist
from typing import Any

import numpy as np

from worldagent.analysis import surrogate
from worldagent.analysis.mixtures import (
    Hits,
    Proposal,
    around_hits,
    blend,
    effective_sample_size,
    fit_mixture,
    importance_weights,
    sample_mixture,
)
from worldagent.errors import WorldagentError
from worldagent.search.campaign import evaluation_seed

METHODS = ("mc", "is")
PROPOSALS = ("search", "surrogate")
BATCH = 1000  # worlds per call of evaluate (a generation of the store campaign)
MC_STREAM, IS_STREAM = 2, 3  # latent streams default_rng([seed, stream]): not random search's (1)
MIN_HITS = 10  # events seen before a target width may stop sampling (the intervals are poor below)
# Batches the surrogate samples before a target width may stop it: after one batch of 250 its normal interval covered
# racing's brute force in 12 of 15 seeds x events (docs/failure-rate.md). The search keeps its recorded one-batch rule.
MIN_BATCHES = 2


@dataclass(frozen=True)
class Scored:
    """What an estimator needs of n evaluated worlds.

    Attributes:
        margin: f64[n] how far each world is inside the event (> 0 inside, < 0 outside).
        event: bool[n] which worlds are in the event.
        episodes: episodes played for them.
    """

    margin: np.ndarray
    event: np.ndarray
    episodes: int


Evaluate = Callable[[np.ndarray, np.ndarray], Scored]


@dataclass(frozen=True)
class Estimate:
    """P(event) with its interval and cost.

    Attributes:
        method: "mc" or "is".
        estimate, low, high: P and its interval.
        worlds, episodes: all spent, the proposal's search included.
        hits: worlds in the event among those the estimate averages.
        confidence: of the interval.
        search_worlds: of ``worlds``, those spent learning the proposal (importance sampling).
        ess: (Σw)² / Σw² over the sampled worlds' weights (importance sampling).
        event_ess: the same over the weights of the worlds in the event: how many equally
            weighted hits the estimate is worth.
    """

    method: str
    estimate: float
    low: float
    high: float
    worlds: int
    episodes: int
    hits: int
    confidence: float = 0.95
    search_worlds: int = 0
    ess: float | None = None
    event_ess: float | None = None

    @property
    def relative_half_width(self) -> float:
        """Half the interval's width over the estimate (inf when the estimate is 0)."""
        return (self.high - self.low) / (2 * self.estimate) if self.estimate > 0 else float("inf")

    def as_dict(self) -> dict:
        return {**asdict(self), "relative_half_width": self.relative_half_width}


@dataclass(frozen=True)
class ImportanceConfig:
    """Settings of ``importance_sampling``.

    Attributes:
        round_worlds: worlds per cross-entropy round.
        max_rounds: rounds at most (the search stops once the elites are all in the event).
        elite_fraction: the top fraction of a round the proposal is fitted to.
        prior_weight: α, the prior's share of the mixture (weights ≤ 1/α).
        components: shifted priors in the search's proposal at most (1: a single mean shift);
            the number is chosen per round by BIC on the weighted elites.
        bandwidth: after the search, the proposal is N(z_i, bandwidth² I) around every event
            world z_i found so far, weighted by p/q, refitted after each batch (at most 1; None:
            keep the search's mixture of shifted priors).
        wide_share: the search's mixture's share of g beside the kernels: it keeps sampling around
            the regions the search found, where kernels may not reach yet.
        proposal: "search" (the cross-entropy method above) or "surrogate": a pool of ``pool``
            worlds from the prior, ``pilot`` of them evaluated, the rest drawn with the chances
            a model of their descriptors gives (``analysis.surrogate``; ``round_worlds`` to
            ``wide_share`` then unused).
    """

    round_worlds: int = 500
    max_rounds: int = 10
    elite_fraction: float = 0.1
    prior_weight: float = 0.1
    components: int = 8
    bandwidth: float | None = 0.7
    wide_share: float = 0.3
    proposal: str = "surrogate"
    pool: int = 200_000
    pilot: int = 500

    def validate(self) -> None:
        if self.proposal not in PROPOSALS:
            raise WorldagentError(f"proposal {self.proposal!r}; use {' or '.join(PROPOSALS)}.")
        _check_count("pool", self.pool)
        _check_count("pilot", self.pilot)
        if self.pilot >= self.pool:
            raise WorldagentError(f"pilot={self.pilot} of a pool of {self.pool}; the pilot must be a part of the pool (raise pool).")
        _check_count("round_worlds", self.round_worlds)
        _check_count("max_rounds", self.max_rounds)
        _check_count("components", self.components)
        if not 0 <= self.wide_share < 1:
            raise WorldagentError(f"wide_share={self.wide_share}; pass a fraction in [0, 1).")
        for name in ("elite_fraction", "prior_weight"):
            if not 0 < getattr(self, name) < 1:
                raise WorldagentError(f"{name}={getattr(self, name)}; pass a fraction between 0 and 1.")
        if self.bandwidth is not None and not 0 < self.bandwidth <= 1:
            raise WorldagentError(f"bandwidth={self.bandwidth}; pass a standard deviation in (0, 1], or None for the search's mixture.")
        if self.round_worlds * self.elite_fraction < 2:
            raise WorldagentError(f"{self.round_worlds} worlds per round keep fewer than 2 elites; raise round_worlds or elite_fraction.")


# -- intervals -------------------------------------------------------------------------------------


def clopper_pearson(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """The exact binomial (Clopper–Pearson) interval of a probability with k successes in n trials.

    Beta quantiles from ``scipy.stats.beta`` (scipy comes with jax).

    Returns:
        (low, high): low = 0 when k = 0, high = 1 when k = n.
    """
    from scipy.stats import beta

    if isinstance(k, bool) or isinstance(n, bool) or int(k) != k or int(n) != n or not 0 <= k <= n or n < 1:
        raise WorldagentError(f"k={k}, n={n}; pass whole numbers with 0 <= k <= n and n >= 1.")
    _check_confidence(confidence)
    tail = (1 - confidence) / 2
    low = 0.0 if k == 0 else float(beta.ppf(tail, k, n - k + 1))
    high = 1.0 if k == n else float(beta.ppf(1 - tail, k + 1, n - k))
    return low, high


def inverse_binomial(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """The exact interval of a probability when sampling stopped at the k-th success, on trial n.

    The k-th success comes by trial n exactly when n trials hold k or more successes, so
    P(N <= n) and P(N >= n) are binomial tails and their bounds Beta quantiles. The unbiased
    estimate under this rule is (k − 1) / (n − 1) (Haldane, 1945).

    Returns:
        (low, high): high = 1 when k = n.
    """
    from scipy.stats import beta

    if isinstance(k, bool) or isinstance(n, bool) or int(k) != k or int(n) != n or not 1 <= k <= n:
        raise WorldagentError(f"k={k}, n={n}; pass whole numbers with 1 <= k <= n.")
    _check_confidence(confidence)
    tail = (1 - confidence) / 2
    return float(beta.ppf(tail, k, n - k + 1)), 1.0 if k == n else float(beta.ppf(1 - tail, k, n - k))


def hits_for_width(target_width: float, confidence: float = 0.95) -> int:
    """The fewest hits k at which inverse binomial sampling's interval is within ±target_width · P for any rare P.

    For a rare event the interval is [Γ_k(α/2), Γ_k(1 − α/2)] / n, a Gamma(k) quantile pair
    about the estimate (k − 1) / n, so its relative half-width falls with k alone (±50% at 95%:
    k = 18). Larger P narrow it.
    """
    from scipy.stats import gamma

    tail = (1 - confidence) / 2
    k = 2
    while (gamma.ppf(1 - tail, k) - gamma.ppf(tail, k)) / (2 * (k - 1)) > target_width:
        k += 1
    return k


def weighted_interval(terms: np.ndarray, confidence: float = 0.95, pool: int | None = None) -> tuple[float, float, float]:
    """(mean, low, high) of importance-sampling terms f64[n] = w · 1[event].

    A normal approximation: mean ± z · sd / √n, clipped to [0, 1]. It is good once the event
    has been hit a few dozen times with weights of similar size (``Estimate.event_ess``). With
    ``pool`` (worlds drawn from a pool of that many prior worlds), the pool's own binomial
    variance mean · (1 − mean) / pool is added.
    """
    _check_confidence(confidence)
    terms = np.asarray(terms, np.float64)
    mean = float(terms.mean())
    error = float(terms.std(ddof=1) / np.sqrt(len(terms))) if len(terms) > 1 else float("inf")
    error = error if pool is None else float(np.sqrt(error**2 + mean * (1 - mean) / pool))
    spread = NormalDist().inv_cdf(1 - (1 - confidence) / 2) * error
    return mean, max(0.0, mean - spread), min(1.0, mean + spread)


# -- the event -------------------------------------------------------------------------------------


def event_margin(clauses: Sequence, means: Mapping[str, np.ndarray]) -> np.ndarray:
    """f64[n]: each world's margin inside the event, the smallest over its clauses (-inf where a metric is NaN).

    ``clauses``: a ``Selection``'s; ``means``: {metric: f64[n]} per-world means.
    """
    margins = []
    for clause in clauses:
        values = np.asarray(means[clause.metric or clause.name], np.float64)
        past = values - clause.number
        margin = {"<": -past, "<=": -past, ">": past, ">=": past, "==": -np.abs(past), "!=": np.abs(past)}[clause.op]
        margins.append(np.where(np.isfinite(margin), margin, -np.inf))
    return np.min(margins, axis=0)


def score_means(selection: Any, means: Mapping[str, np.ndarray], episodes: int) -> Scored:
    """The margins and event of worlds from their per-world means {metric: f64[n]} (``selection``'s clauses)."""
    event = np.logical_and.reduce([clause.holds(means[clause.metric or clause.name]) for clause in selection.clauses])
    return Scored(event_margin(selection.clauses, means), np.asarray(event, bool), int(episodes))


def score_worlds(selection: Any, worlds: Sequence) -> Scored:
    """The margins and event of evaluated worlds (anything with ``.episodes``: outcomes, stored evaluations)."""
    return score_means(selection, selection.world_means(worlds), sum(len(world.episodes) for world in worlds))


# -- Monte Carlo -----------------------------------------------------------------------------------


def monte_carlo(
    evaluate: Evaluate, dim: int, worlds: int, *, seed: int = 0, batch: int = 1000, confidence: float = 0.95, target_width: float | None = None
) -> Estimate:
    """P(event) from worlds z ~ N(0, I), with an exact interval.

    With a fixed number of worlds the interval is Clopper–Pearson's. With ``target_width``,
    sampling stops at the k-th world in the event, k = ``hits_for_width`` (inverse binomial
    sampling), and the estimate and its exact interval are those of that stopping rule
    (``inverse_binomial``). Stopping at the first batch whose Clopper–Pearson interval looked
    narrow picks batches where the hits came early, so that interval did not hold its level: on
    harvest at 1e-3 it missed the brute force (docs/failure-rate.md).

    Args:
        evaluate: ``(z f64[n, dim], seeds int[n]) -> Scored``.
        dim: the latent dimension.
        worlds: worlds to sample (at most, with ``target_width``).
        seed: seed of the latents and of every evaluation.
        batch: worlds per call of ``evaluate``.
        confidence: of the interval.
        target_width: stop at the hit that brings the interval within ±target_width · P.

    Returns:
        An ``Estimate`` (estimate 0 and high = the interval's bound when no world is in the event).
        When it stopped at a hit, ``worlds`` counts the worlds up to that hit and ``episodes``
        all that were played (the rest of its batch too).
    """
    check_budget(worlds, target_width, dim=dim, batch=batch, confidence=confidence)
    rng = np.random.default_rng([seed, MC_STREAM])
    spend, hits = _Spender(evaluate, seed), 0
    needed = None if target_width is None else hits_for_width(target_width, confidence)
    while spend.worlds < worlds:
        before = spend.worlds
        event = spend(rng.standard_normal((min(batch, worlds - spend.worlds), dim))).event
        if needed is not None and hits + event.sum() >= needed:
            stop = before + int(np.flatnonzero(event)[needed - hits - 1]) + 1
            low, high = inverse_binomial(needed, stop, confidence)
            return Estimate("mc", (needed - 1) / (stop - 1), low, high, stop, spend.episodes, needed, confidence)
        hits += int(event.sum())
    low, high = clopper_pearson(hits, spend.worlds, confidence)
    return Estimate("mc", hits / spend.worlds, low, high, spend.worlds, spend.episodes, hits, confidence)


# -- importance sampling ---------------------------------------------------------------------------


def importance_sampling(
    evaluate: Evaluate,
    dim: int,
    worlds: int,
    *,
    config: ImportanceConfig = ImportanceConfig(),
    seed: int = 0,
    batch: int = 1000,
    confidence: float = 0.95,
    target_width: float | None = None,
    describe: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Estimate:
    """P(event) by importance sampling from a proposal learned by the cross-entropy method (module docstring), or
    shaped by a surrogate (``config.proposal``, ``surrogate_sampling``).

    The interval is a normal approximation on the weighted mean (``weighted_interval``).

    Args:
        evaluate, dim, seed, batch, confidence, target_width: as for ``monte_carlo``.
        worlds: worlds sampled from the mixture after the search (at most, with ``target_width``).
        config: the search's and the mixture's settings.
        describe: ``(z f64[n, dim]) -> f64[n, k]`` descriptors of the worlds G(z), for the
            surrogate (None: it reads the latents only).

    Returns:
        An ``Estimate``; ``worlds``, ``episodes`` include the search's (``search_worlds``).

    Raises:
        WorldagentError: when no sampled world is in the event (impossible, or not found).
    """
    check_budget(worlds, target_width, config, dim=dim, batch=batch, confidence=confidence)
    if config.proposal == "surrogate":
        return surrogate_sampling(
            evaluate, dim, worlds, config=config, seed=seed, batch=batch, confidence=confidence, target_width=target_width, describe=describe
        )
    rng = np.random.default_rng([seed, IS_STREAM])
    spend = _Spender(evaluate, seed)
    proposal, best, hits = learn_proposal(spend, rng, dim, config)
    wide, search_worlds = proposal, spend.worlds
    weights, events = [], []
    while spend.worlds - search_worlds < worlds:
        if config.bandwidth is not None and len(hits.weights) >= 2:  # each batch is unbiased given the ones before
            proposal = blend(wide, around_hits(hits.z, hits.weights, config.bandwidth, rng), config.wide_share)
        z = sample_mixture(rng, proposal, config.prior_weight, min(batch, worlds - (spend.worlds - search_worlds)))
        scored = spend(z)
        weights.append(importance_weights(z, proposal, config.prior_weight))
        events.append(scored.event)
        hits = hits.add(z[scored.event], weights[-1][scored.event])
        best = max(best, float(np.max(scored.margin)))
        terms = np.concatenate(weights) * np.concatenate(events)
        if _narrow_enough(int(np.sum(np.concatenate(events))), weighted_interval(terms, confidence)[1:], float(terms.mean()), target_width):
            break
    return _weighted_estimate(np.concatenate(weights), np.concatenate(events), spend, search_worlds, best, confidence)


def surrogate_sampling(
    evaluate: Evaluate,
    dim: int,
    worlds: int,
    *,
    config: ImportanceConfig,
    seed: int = 0,
    batch: int = 1000,
    confidence: float = 0.95,
    target_width: float | None = None,
    describe: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Estimate:
    """P(event) by importance sampling over a pool of prior worlds, shaped by a surrogate (``analysis.surrogate``).

    1. *Pool*: M = ``config.pool`` latents z ~ N(0, I), described (a decode each, no episode).
    2. *Pilot*: the pool's first ``config.pilot`` worlds are evaluated; a ridge regression of
       their margins on the worlds' features gives every pool world a chance c_j of the event.
    3. *Sampling*: batches of pool worlds drawn with replacement with q_j = α/M + (1 − α) c_j / Σc,
       each played afresh; a term is w_j · 1[event] with w_j = 1 / (M q_j) ≤ 1/α.

    The terms' mean is unbiased for the pool's event fraction, which is unbiased for P; the
    interval adds the pool's own binomial variance P(1 − P)/M (with P estimated) to the terms'.
    The proposal is fixed after the pilot, so the terms are independent. The pilot's worlds are
    spent, counted (``search_worlds``) and not in the mean.
    """
    rng = np.random.default_rng([seed, IS_STREAM])
    pool = rng.standard_normal((config.pool, dim))
    spend = _Spender(evaluate, seed)
    margins = np.concatenate([spend(pool[start : min(start + batch, config.pilot)]).margin for start in range(0, config.pilot, batch)])
    finite = margins[np.isfinite(margins)]
    best = float(finite.max()) if finite.size else -np.inf
    features = surrogate.features(pool, None if describe is None else describe(pool))
    shares = surrogate.pool_shares(surrogate.log_chances(features, features[: config.pilot], margins), config.prior_weight)
    weight_of = 1.0 / (config.pool * shares)
    weights, events = [], []
    while spend.worlds - config.pilot < worlds:
        drawn = rng.choice(config.pool, size=min(batch, worlds - (spend.worlds - config.pilot)), p=shares)
        scored = spend(pool[drawn])
        weights.append(weight_of[drawn])
        events.append(scored.event)
        best = max(best, float(np.max(scored.margin)))
        terms = np.concatenate(weights) * np.concatenate(events)
        interval = weighted_interval(terms, confidence, config.pool)
        enough = len(events) >= MIN_BATCHES and _narrow_enough(int(np.sum(np.concatenate(events))), interval[1:], interval[0], target_width)
        if enough:
            break
    return _weighted_estimate(np.concatenate(weights), np.concatenate(events), spend, config.pilot, best, confidence, config.pool)


def _weighted_estimate(
    weight: np.ndarray, event: np.ndarray, spend: _Spender, search_worlds: int, best: float, confidence: float, pool: int | None = None
) -> Estimate:
    """Importance sampling's ``Estimate`` from the sampled worlds' weights f64[n] and events bool[n] (``pool``: the
    surrogate's, else the search's)."""
    if not event.any():
        longer = "search longer (more rounds or worlds per round)" if pool is None else "raise the pilot or the pool"
        hint = f"the closest came within {-best:.3g} of it: check the thresholds, or {longer}"
        hint = "sample more worlds" if best >= 0 else hint
        raise WorldagentError(f"the event never occurred in the {len(event)} worlds sampled for importance sampling ({hint}).")
    estimate, low, high = weighted_interval(weight * event, confidence, pool)
    return Estimate(
        "is", estimate, low, high, spend.worlds, spend.episodes, int(event.sum()), confidence, search_worlds,
        effective_sample_size(weight), effective_sample_size(weight * event),
    )  # fmt: skip


def learn_proposal(
    spend: Callable[[np.ndarray], Scored], rng: np.random.Generator, dim: int, config: ImportanceConfig
) -> tuple[Proposal, float, Hits]:
    """The cross-entropy method: (the proposal, the best margin seen, the event worlds found); ``spend(z) -> Scored``
    evaluates."""
    proposal, best, hits = Proposal.shift(np.zeros(dim)), -np.inf, Hits(np.zeros((0, dim)), np.zeros(0))
    for _ in range(config.max_rounds):
        z = sample_mixture(rng, proposal, config.prior_weight, config.round_worlds)
        scored = spend(z)
        finite = scored.margin[np.isfinite(scored.margin)]
        if finite.size == 0:
            raise WorldagentError("the event's metrics are NaN on every world of a search round; check the policy and the metrics.")
        best = max(best, float(finite.max()))
        level = min(0.0, float(np.quantile(finite, 1 - config.elite_fraction)))  # never past the event itself
        elite, weights = elites(scored, level), importance_weights(z, proposal, config.prior_weight)
        hits = hits.add(z[scored.event], weights[scored.event])
        proposal = fit_mixture(z[elite], weights[elite], config.components, rng)
        if level >= 0 and scored.event.sum() >= 2:  # fitted to the event's worlds: to the prior on it
            break
    return proposal, best, hits


def elites(scored: Scored, level: float) -> np.ndarray:
    """bool[n]: the worlds to fit: the event's once the bar reaches it, else those strictly past the bar (a tie at it,
    from a discrete metric, would stall the search), else those at it; the first choice with two worlds or more."""
    choices = ((scored.event,) if level >= 0 else ()) + (scored.margin > level,)
    return next((choice for choice in choices if choice.sum() >= 2), scored.margin >= level)


# -- settings --------------------------------------------------------------------------------------


def methods(method: str) -> tuple[str, ...]:
    """The estimators ``method`` ("mc", "is" or "both") names."""
    if method not in (*METHODS, "both"):
        raise WorldagentError(f"unknown method {method!r}; use mc, is or both.")
    return METHODS if method == "both" else (method,)


def check_budget(worlds: int, target_width: float | None = None, importance: ImportanceConfig | None = None, **counts: int) -> None:
    """Refuse a bad budget or setting with one line, before anything is evaluated or stored (``counts``: dim, batch)."""
    confidence = counts.pop("confidence", 0.95)
    for name, value in {"worlds": worlds, **counts}.items():
        _check_count(name, value)
    _check_confidence(confidence)
    if target_width is not None and not target_width > 0:
        raise WorldagentError(f"target width {target_width}; pass a positive relative half-width such as 0.5 (±50%).")
    if importance is not None:
        importance.validate()


# -- helpers ---------------------------------------------------------------------------------------


class _Spender:
    """Calls ``evaluate`` one generation at a time with the campaign seeds; counts worlds and episodes."""

    def __init__(self, evaluate: Evaluate, seed: int):
        self.evaluate, self.seed = evaluate, int(seed)
        self.generation = self.worlds = self.episodes = 0

    def __call__(self, z: np.ndarray) -> Scored:
        seeds = np.array([evaluation_seed(self.seed, self.generation, slot) for slot in range(len(z))], np.int64)
        scored = self.evaluate(z, seeds)
        if np.shape(scored.margin) != (len(z),) or np.shape(scored.event) != (len(z),):
            raise WorldagentError(f"evaluate returned margins {np.shape(scored.margin)} and events {np.shape(scored.event)} for {len(z)} worlds.")
        self.generation, self.worlds, self.episodes = self.generation + 1, self.worlds + len(z), self.episodes + int(scored.episodes)
        return Scored(np.asarray(scored.margin, np.float64), np.asarray(scored.event, bool), int(scored.episodes))


def _narrow_enough(hits: int, interval: tuple[float, float], estimate: float, target_width: float | None) -> bool:
    """Whether sampling may stop: a target width reached with at least ``MIN_HITS`` hits."""
    return target_width is not None and hits >= MIN_HITS and estimate > 0 and (interval[1] - interval[0]) / (2 * estimate) <= target_width


def _check_count(name: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise WorldagentError(f"{name}={value!r}; pass a whole number of at least 1.")


def _check_confidence(confidence: float) -> None:
    if not 0 < confidence < 1:
        raise WorldagentError(f"confidence={confidence}; pass a level between 0 and 1, e.g. 0.95.")
