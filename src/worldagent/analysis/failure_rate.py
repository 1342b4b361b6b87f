"""The probability of a failure under the world distribution (DESIGN.md "Failure probability").

An event (a selection such as ``crash_rate > 0.5``, per-world means over its episodes) has a
probability P under the generator's prior: worlds G(z), z ~ N(0, I). Two estimators, both
pure functions of an ``evaluate(z f64[n, dim], seeds int[n]) -> Scored`` callable, so that a
closed-form toy (event ``z[0] > 3``) tests them without any environment:

- ``monte_carlo``: z ~ N(0, I); k of n worlds in the event; P = k / n with the exact binomial
  (Clopper–Pearson) interval. Honest at any P, but a rare event needs ~ 4 / (P r²) worlds for a
  95% interval of ±r·P.
- ``importance_sampling``: two stages.

  1. *Search*: the cross-entropy method (Rubinstein & Kroese) learns a mixture of shifted priors
     Σ_k π_k N(c_k, I). Each round samples worlds, ranks them by the event's *margin* (how far
     past its thresholds a world is; > 0 inside), lowers the bar to the top ``elite_fraction``
     (never past the event itself), and fits the mixture to the elites weighted by p/q: the
     cross-entropy update in this family is weighted EM, run for 1 to ``components``
     components and kept at the lowest BIC. With ``bandwidth``, the next round draws from that
     mixture (share ``wide_share``) and kernels N(z_i, h² I) around every world so far past the
     bar: where the event is a union of small cells (a generator that repairs to its dataset)
     shifted priors barely climb (racing: 0-5 hits a round of 500 at p ≈ 1e-3), kernels do.
  2. *Sampling*, in batches from the defensive mixture q = α N(0, I) + (1 − α) g, which keeps
     every weight ≤ 1/α. Before each batch, g is refitted: ``wide_share`` of the search's
     mixture plus N(z_i, h² I) kernels (h = ``bandwidth``) around every event world z_i found so
     far, shares ∝ its weight: a kernel estimate of the prior on the event that grows as regions
     are found (``analysis.proposals`` says why these families).

  Every world drawn, the search's included, is in the estimate: P = mean(w · 1[event]) with w =
  p / q̄, q̄ the average of all the proposals used, each weighted by its worlds (``Pool.weights``,
  deterministic-mixture weights). Why not each world's own p/q_r: the search's first rounds
  are close to the prior, whose rare hits would weigh 1/P times the rest and widen the interval
  more than their worlds narrow it; under q̄ such a hit gets the weight the later proposals give
  it. The price: proposals fitted after a world was drawn enter its weight, so the mean is
  consistent, not exactly unbiased (as the stopping rule already makes any of these means): on
  the toys, 20 seeds of 2,000 worlds after the search, mean estimates 0.95-0.97 P. The
  interval treats the terms as independent. The search stops early once ``search_hits`` event
  worlds have been found (kernels need only a few hits to grow from), and sampling stops as
  soon as the pooled interval meets ``target_width``.

The estimator's g-th call of ``evaluate`` is generation g, its worlds played with
``evaluation_seed(seed, g, slot)``; ``StoredEvaluate`` (``analysis.failure_rate_store``) keeps
each estimate as one store campaign and resumes it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from statistics import NormalDist
from typing import Any

import numpy as np

from worldagent.analysis.failure_rate_search import ImportanceConfig, _check_count, elites, learn_proposal
from worldagent.analysis.failure_rate_store import StoredEvaluate, campaign_name
from worldagent.analysis.proposals import (
    MAX_CENTRES,
    Pool,
    Proposal,
    around_hits,
    blend,
    component_logs,
    effective_sample_size,
    fit_mixture,
    importance_weights,
    log_mixture,
    sample_mixture,
    weighted_em,
)
from worldagent.errors import WorldagentError
from worldagent.search.campaign import evaluation_seed

__all__ = [  # the split-off modules' names stay importable from here
    "MAX_CENTRES", "ImportanceConfig", "Pool", "Proposal", "StoredEvaluate", "around_hits", "blend", "campaign_name",
    "component_logs", "effective_sample_size", "elites", "fit_mixture", "importance_weights", "learn_proposal",
    "log_mixture", "sample_mixture", "weighted_em",
]  # fmt: skip

METHODS = ("mc", "is")
BATCH = 1000  # worlds per call of evaluate (a generation of the store campaign)
MC_STREAM, IS_STREAM = 2, 3  # latent streams default_rng([seed, stream]): not random search's (1)
MIN_HITS = 10  # events seen before a target width may stop sampling (the intervals are poor below)


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


def weighted_interval(terms: np.ndarray, confidence: float = 0.95) -> tuple[float, float, float]:
    """(mean, low, high) of importance-sampling terms f64[n] = w · 1[event].

    A normal approximation: mean ± z · sd / √n, clipped to [0, 1]. It is good once the event
    has been hit a few dozen times with weights of similar size (``Estimate.event_ess``).
    """
    _check_confidence(confidence)
    terms = np.asarray(terms, np.float64)
    mean = float(terms.mean())
    error = float(terms.std(ddof=1) / np.sqrt(len(terms))) if len(terms) > 1 else float("inf")
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
    """P(event) from worlds z ~ N(0, I), with the exact binomial interval.

    Args:
        evaluate: ``(z f64[n, dim], seeds int[n]) -> Scored``.
        dim: the latent dimension.
        worlds: worlds to sample (at most, with ``target_width``).
        seed: seed of the latents and of every evaluation.
        batch: worlds per call of ``evaluate``.
        confidence: of the interval.
        target_width: stop once the interval is within ±target_width · P (and ``MIN_HITS`` hits).

    Returns:
        An ``Estimate`` (estimate 0 and high = the interval's bound when no world is in the event).
    """
    check_budget(worlds, target_width, dim=dim, batch=batch, confidence=confidence)
    rng = np.random.default_rng([seed, MC_STREAM])
    spend, hits = _Spender(evaluate, seed), 0
    while spend.worlds < worlds:
        hits += int(spend(rng.standard_normal((min(batch, worlds - spend.worlds), dim))).event.sum())
        if _narrow_enough(hits, clopper_pearson(hits, spend.worlds, confidence), hits / spend.worlds, target_width):
            break
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
) -> Estimate:
    """P(event) by importance sampling from a proposal learned by the cross-entropy method (module docstring).

    The interval is a normal approximation on the weighted mean (``weighted_interval``).

    Args:
        evaluate, dim, seed, batch, confidence, target_width: as for ``monte_carlo``.
        worlds: worlds sampled from the mixture after the search (at most, with ``target_width``).
        config: the search's and the mixture's settings.

    Returns:
        An ``Estimate``; ``worlds``, ``episodes`` include the search's (``search_worlds``).

    Raises:
        WorldagentError: when no sampled world is in the event (impossible, or not found).
    """
    check_budget(worlds, target_width, config, dim=dim, batch=batch, confidence=confidence)
    rng = np.random.default_rng([seed, IS_STREAM])
    spend = _Spender(evaluate, seed)

    def narrow(pool: Pool, weights: np.ndarray) -> bool:
        terms = weights * pool.event
        return _narrow_enough(int(pool.event.sum()), weighted_interval(terms, confidence)[1:], float(terms.mean()), target_width)

    wide, best, pool = learn_proposal(spend, rng, dim, config, narrow)
    search_worlds = spend.worlds
    while (left := worlds - (spend.worlds - search_worlds)) > 0:
        weights = pool.weights(config.prior_weight)
        if narrow(pool, weights):
            break
        proposal = wide
        if config.bandwidth is not None and pool.event.sum() >= 2:
            proposal = blend(wide, around_hits(pool.z[pool.event], weights[pool.event], config.bandwidth, rng), config.wide_share)
        # batches grow by 1/16 of the pool: each refit weighs every pooled world, so their total cost stays ~linear
        z = sample_mixture(rng, proposal, config.prior_weight, min(max(batch, spend.worlds // 16), left))
        scored = spend(z)
        pool, best = pool.add(z, scored.margin, scored.event, proposal), max(best, float(np.max(scored.margin)))
    if not pool.event.any():
        hint = f"the closest came within {-best:.3g} of it: check the thresholds, or search longer (more rounds or worlds per round)"
        hint = "sample more worlds" if best >= 0 else hint
        raise WorldagentError(f"the event never occurred in the {len(pool.event)} worlds sampled for importance sampling ({hint}).")
    weight = pool.weights(config.prior_weight)
    estimate, low, high = weighted_interval(weight * pool.event, confidence)
    return Estimate(
        "is", estimate, low, high, spend.worlds, spend.episodes, int(pool.event.sum()), confidence, search_worlds,
        effective_sample_size(weight), effective_sample_size(weight * pool.event),
    )  # fmt: skip


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


def _check_confidence(confidence: float) -> None:
    if not 0 < confidence < 1:
        raise WorldagentError(f"confidence={confidence}; pass a level between 0 and 1, e.g. 0.95.")
