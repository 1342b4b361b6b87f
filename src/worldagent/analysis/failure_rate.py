"""The probability of a failure under the world distribution (DESIGN.md "Failure probability").

An event (a selection such as ``crash_rate > 0.5``, per-world means over its episodes) has a
probability P under the generator's prior: worlds G(z), z ~ N(0, I). Two estimators, both
pure functions of an ``evaluate(z f64[n, dim], seeds int[n]) -> Scored`` callable, so that a
closed-form toy (event ``z[0] > 3``) tests them without any environment:

- ``monte_carlo``: z ~ N(0, I); k of n worlds in the event; P = k / n with the exact binomial
  (Clopper–Pearson) interval, or, sampled to a target width, stopped at a fixed k-th hit with
  that rule's exact interval (inverse binomial sampling). Honest at any P, but a rare event
  needs ~ 4 / (P r²) worlds for a 95% interval of ±r·P.
- ``importance_sampling``: worlds drawn where the event is likelier, weighted back to the prior;
  one of two samplers (``ImportanceConfig.proposal``):

  - ``surrogate`` (the default; ``surrogate_sampling``, ``analysis.pooled``): a pool of prior
    worlds is described (no episode); a pilot of them is played, a model of the event's margin
    from the worlds' descriptors (``analysis.surrogate``) cuts the pool into strata of known
    mass, and each stratum is sampled as much as the mass it may hold asks. After the pilot it
    predicts its gain over Monte Carlo (episodes and seconds, describing the pool included) and
    falls back to Monte Carlo below 1.5x. Its interval counts a stratum with no hit yet.
  - ``learned`` (``analysis.learned``): the surrogate's pool and pilot, then rounds in the
    cross-entropy method's manner: each raises a level on the event's margin, draws the pool's
    strata toward it and refits the model on the worlds played (worlds with identical descriptors,
    one repaired-to world, share what is learned). Only the final draws enter the estimate.
  - ``search`` (``analysis.cross_entropy``): a cross-entropy search for a mixture of shifted
    priors, then kernels around the event worlds found, mixed with the prior.

The estimator's g-th call of ``evaluate`` is generation g, its worlds played with
``evaluation_seed(seed, g, slot)`` as in a campaign. ``StoredEvaluate`` makes ``evaluate`` from
an agent's evaluator and a run store: each estimate is one store campaign (``campaign_name``)
whose generations are those calls (for importance sampling, the search's rounds first). A rerun
replays the stored generations (their latents must match) and evaluates only what is missing,
so a killed run loses nothing. One campaign per estimate, rather than one per search round,
keeps the store's campaigns readable and resuming a single lookup.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from worldagent.analysis import learned, pooled, surrogate
from worldagent.analysis.intervals import (  # noqa: F401  (the interval functions are part of this module's interface)
    bounded,
    check_confidence,
    clopper_pearson,
    hits_for_width,
    inverse_binomial,
    weighted_interval,
)
from worldagent.analysis.mixtures import effective_sample_size
from worldagent.errors import WorldagentError
from worldagent.search.campaign import evaluation_seed

METHODS = ("mc", "is")
PROPOSALS = ("search", "surrogate", "learned")
POOLED = ("surrogate", "learned")  # the proposals drawing from a described pool of prior worlds (``analysis.pooled``)
BATCH = 1000  # worlds per call of evaluate (a generation of the store campaign)
MC_STREAM, IS_STREAM = 2, 3  # latent streams default_rng([seed, stream]): not random search's (1)
POOL_LATENTS, POOL_DRAWS, FALLBACK_DRAWS, LEARN_DRAWS = 1, 2, 3, 4  # the surrogate's sub-streams of IS_STREAM
MIN_HITS = 10  # events seen before a target width may stop the search's sampling (the intervals are poor below)
MAX_WORLDS = 10_000_000  # worlds (or a pool) larger than this are refused before any work: a typo, not a budget


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
Say = Callable[[str], None]
Prior = Callable[[np.random.Generator, int, int], np.ndarray]  # (rng, n, dim) -> z f64[n, dim]: the next n prior latents


def standard_prior(rng: np.random.Generator, n: int, dim: int) -> np.ndarray:
    """z ~ N(0, I): the generator's prior. A stream's first n draws do not depend on how many follow (prefixes)."""
    return rng.standard_normal((n, dim))


@dataclass(frozen=True)
class Estimate:
    """P(event) with its interval and cost.

    Attributes:
        method: "mc" or "is" (an importance-sampling estimate that fell back is "mc", with ``fallback``).
        estimate, low, high: P and its interval, all in [0, 1] with low <= estimate <= high.
        worlds, episodes: all spent, the proposal's search or pilot included.
        hits: worlds in the event among those the estimate averages.
        confidence: of the interval.
        search_worlds: of ``worlds``, those spent learning the proposal (importance sampling's search or pilot).
        ess: (Σw)² / Σw² over the sampled worlds' weights (importance sampling).
        event_ess: the same over the weights of the worlds in the event: how many equally
            weighted hits the estimate is worth.
        note: why the interval is wider than asked (a cap), or None.
        fallback: why importance sampling ran Monte Carlo instead, or None.
        plan: what the surrogate's pilot predicted (``pooled.Plan.as_dict``; timings, so not compared).
        seconds: wall time of the estimate (not compared).
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
    note: str | None = None
    fallback: str | None = None
    plan: dict | None = field(default=None, compare=False)
    seconds: float = field(default=0.0, compare=False)

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
        prior_weight: α, the prior's share of the search's mixture (weights ≤ 1/α).
        components: shifted priors in the search's proposal at most (1: a single mean shift);
            the number is chosen per round by BIC on the weighted elites.
        bandwidth: after the search, the proposal is N(z_i, bandwidth² I) around every event
            world z_i found so far, weighted by p/q, refitted after each batch (at most 1; None:
            keep the search's mixture of shifted priors).
        wide_share: the search's mixture's share of g beside the kernels: it keeps sampling around
            the regions the search found, where kernels may not reach yet.
        proposal: "search" (``analysis.cross_entropy``), "surrogate" (``analysis.pooled``): a
            pool of prior worlds, ``pilot`` of them evaluated, the rest stratified by a model of
            their descriptors (``round_worlds`` to ``wide_share`` then unused), or "learned"
            (``analysis.learned``): the surrogate's pool and pilot, then rounds that refit the model
            on the worlds played, each toward the last one's near-misses.
        pool: the surrogate's pool of described prior worlds (None: as many as ``pool_seconds`` of
            describing buy, timed on a sample, at most ``pooled.DEFAULT_POOL``).
        pool_seconds: the time budget for describing the pool when ``pool`` is None.
    """

    round_worlds: int = 500
    max_rounds: int = 10
    elite_fraction: float = 0.1
    prior_weight: float = 0.1
    components: int = 8
    bandwidth: float | None = 0.7
    wide_share: float = 0.3
    proposal: str = "surrogate"
    pool: int | None = None
    pilot: int = 500
    pool_seconds: float = pooled.POOL_SECONDS

    def validate(self) -> None:
        if self.proposal not in PROPOSALS:
            raise WorldagentError(f"proposal {self.proposal!r}; use {' or '.join(PROPOSALS)}.")
        _check_count("pilot", self.pilot)
        if self.pool is not None:
            _check_count("pool", self.pool, pooled.MAX_POOL)
            if self.pilot >= self.pool:
                raise WorldagentError(f"pilot={self.pilot} of a pool of {self.pool}; the pilot must be a part of the pool (raise pool).")
        if not self.pool_seconds > 0:
            raise WorldagentError(f"pool_seconds={self.pool_seconds}; pass a positive time budget in seconds.")
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
    evaluate: Evaluate, dim: int, worlds: int, *, seed: int = 0, batch: int = 1000, confidence: float = 0.95, target_width: float | None = None,
    prior: Prior = standard_prior,
) -> Estimate:  # fmt: skip
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
        prior: draws the latents (``standard_prior``; a benchmark replays recorded worlds with its own).

    Returns:
        An ``Estimate`` (estimate 0 and high = the interval's bound when no world is in the event).
        When it stopped at a hit, ``worlds`` counts the worlds up to that hit and ``episodes``
        all that were played (the rest of its batch too). When ``worlds`` ran out short of the
        width, ``note`` says so and how many worlds the width needs.
    """
    check_budget(worlds, target_width, dim=dim, batch=batch, confidence=confidence)
    started = time.perf_counter()
    found = sample_prior(Spender(evaluate, seed), np.random.default_rng([seed, MC_STREAM]), dim, worlds, batch, confidence, target_width, prior=prior)
    return _timed(found, started)


def sample_prior(
    spend: Spender, rng: np.random.Generator, dim: int, worlds: int, batch: int, confidence: float, target_width: float | None,
    seen: np.ndarray | None = None, prior: Prior = standard_prior,
) -> Estimate:  # fmt: skip
    """Monte Carlo's sampling (``monte_carlo``) with ``spend``; ``seen`` bool[m]: events of prior worlds already played
    (a pilot), counted first, as the stream's first m worlds."""
    seen = np.zeros(0, bool) if seen is None else np.asarray(seen, bool)
    needed = None if target_width is None else hits_for_width(target_width, confidence)
    events, total = [seen], len(seen)
    while total < worlds:
        events.append(spend(prior(rng, min(batch, worlds - total), dim)).event)
        total += len(events[-1])
        hit_at = np.flatnonzero(np.concatenate(events))
        if needed is not None and len(hit_at) >= needed:
            stop = int(hit_at[needed - 1]) + 1
            low, high = inverse_binomial(needed, stop, confidence)
            return Estimate("mc", (needed - 1) / (stop - 1), low, high, stop, spend.episodes, needed, confidence)
    hits = int(np.concatenate(events).sum())
    low, high = clopper_pearson(hits, total, confidence)
    estimate = Estimate("mc", hits / total, low, high, total, spend.episodes, hits, confidence)
    if needed is not None and estimate.relative_half_width > target_width:
        more = f"about {needed / estimate.estimate:,.0f}" if hits else f"more than {total:,}"
        note = f"stopped at its cap of {total:,} worlds short of ±{target_width:.0%}: ±{estimate.relative_half_width:.0%} (the width needs {more} worlds)"
        estimate = Estimate(**{**asdict(estimate), "note": note})
    return estimate


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
    timing: Mapping[str, float] | None = None,
    say: Say | None = None,
    prior: Prior = standard_prior,
) -> Estimate:
    """P(event) by importance sampling: ``surrogate_sampling`` or the cross-entropy search's (``config.proposal``).

    Args:
        evaluate, dim, seed, batch, confidence, target_width: as for ``monte_carlo``.
        worlds: worlds sampled after the search or pilot (at most).
        config: the sampler's settings.
        describe: ``(z f64[n, dim]) -> f64[n, k]`` descriptors of the worlds G(z), for the
            surrogate (None: it reads the latents only).
        timing, say, prior: the surrogate's (``surrogate_sampling``; the search draws from N(0, I) itself).

    Returns:
        An ``Estimate``; ``worlds``, ``episodes`` include the search's or pilot's (``search_worlds``).

    Raises:
        WorldagentError: when the search's sampled worlds never met the event.
    """
    check_budget(worlds, target_width, config, dim=dim, batch=batch, confidence=confidence)
    started = time.perf_counter()
    if config.proposal in POOLED:
        found = surrogate_sampling(
            evaluate, dim, worlds, config=config, seed=seed, batch=batch, confidence=confidence, target_width=target_width,
            describe=describe, timing=timing, say=say, prior=prior,
        )  # fmt: skip
    else:
        from worldagent.analysis.cross_entropy import search_sampling

        found = search_sampling(evaluate, dim, worlds, config=config, seed=seed, batch=batch, confidence=confidence, target_width=target_width)
    return _timed(found, started)


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
    timing: Mapping[str, float] | None = None,
    say: Say | None = None,
    prior: Prior = standard_prior,
) -> Estimate:
    """P(event) from a pool of prior worlds stratified by a surrogate of their descriptors (``analysis.pooled``).

    The pool's first ``config.pilot`` worlds are played and its first ``pooled.TIMED_SAMPLE``
    described, both timed; the plan then says how large a pool ``config.pool_seconds`` buys
    (when ``config.pool`` is None), how many draws the width needs, and the gain over Monte
    Carlo. Below ``pooled.MIN_GAIN`` the pilot's worlds (prior draws) start a Monte Carlo
    estimate (``fallback`` says why); else the rest of the pool is described and the strata drawn.

    Args:
        timing: {"episode_seconds", "describe_seconds"} per world and "described" (pool rows kept from before), to
            replay a recorded plan instead of measuring (a replayed pilot costs no time); an empty mutable mapping is
            filled with what was measured (``stored.KeptTiming`` writes it down before anything is decided).
        say: called with one line before the pool is described, or when falling back.
        prior: draws the pool's latents and the fallback's (``standard_prior``).
    """
    say = say or (lambda line: None)
    pool_rng = np.random.default_rng([seed, IS_STREAM, POOL_LATENTS])
    spend = Spender(evaluate, seed)
    sample = max(config.pilot + 1, min(pooled.TIMED_SAMPLE, config.pool or pooled.TIMED_SAMPLE))
    pool = prior(pool_rng, sample, dim)
    play, describing = pooled.Clock(), pooled.Clock()
    pilot = [
        play.timed(spend, min(batch, config.pilot - start))(pool[start : min(start + batch, config.pilot)]) for start in range(0, config.pilot, batch)
    ]
    margins, seen = np.concatenate([s.margin for s in pilot]), np.concatenate([s.event for s in pilot])
    described = None if describe is None else describing.timed(describe, sample)(pool)
    timing = _timing(timing, describe, play.per_world, describing.per_world, sample)
    size = pooled.pool_size(config.pool, config.pool_seconds, timing["describe_seconds"], sample)
    strata = pooled.stratify(pooled.pool_chances(pool, described, sample, margins))
    plan = pooled.plan(
        strata,
        size,
        config.pilot,
        worlds,
        target_width,
        timing["episode_seconds"],
        timing["describe_seconds"],
        timing.get("described", sample),
        confidence,
        met=int(seen.sum()),
    )
    rounds = learning_worlds(config) - config.pilot
    learning = config.proposal == "learned" and learned.worth_learning(max(strata.probability, seen.mean()), target_width, rounds, confidence)
    if plan.fallback and not learning:
        return _fall_back(spend, plan, config, dim, worlds, batch, confidence, target_width, seen, prior, seed, say)
    if size > sample:
        minutes = plan.describe_total / 60
        say(
            f"describing the pool: {size:,} worlds, about {minutes:.1f} min ({timing['describe_seconds'] * 1e3:.2f} ms a world, timed on {sample:,})."
        )
        pool = np.concatenate([pool, prior(pool_rng, size - sample, dim)])
        described = None if describe is None else describe(pool)
    features = surrogate.features(pool, described, reference=sample)
    if learning:
        say(f"learning the proposal from the pilot's margins: {learned.STAGES} rounds, {rounds:,} worlds, each toward the last one's near-misses.")
        learn_rng = np.random.default_rng([seed, IS_STREAM, LEARN_DRAWS])
        labels = learned.cells(described, size)
        model, probability = learned.learn(spend, learn_rng, pool, features, labels, margins, seen, batch)
        strata = model.strata(probability)
        plan = pooled.plan(
            strata, size, spend.worlds, worlds, target_width, timing["episode_seconds"], timing["describe_seconds"],
            timing.get("described", sample), confidence, "the model learned over the rounds",
        )  # fmt: skip
        if plan.fallback:
            return _fall_back(spend, plan, config, dim, worlds, batch, confidence, target_width, seen, prior, seed, say)
    else:
        strata = pooled.stratify(surrogate.log_chances(features, features[: config.pilot], margins))
    learned_worlds = spend.worlds
    counts = pooled.draws_per_stratum(plan.draws, pooled.allocation(strata))
    drawn = pooled.stratified_draws(np.random.default_rng([seed, IS_STREAM, POOL_DRAWS]), strata, counts)
    event = np.concatenate([spend(pool[drawn[start : start + batch]]).event for start in range(0, len(drawn), batch)])
    stratum = strata.labels[drawn]
    hits = np.bincount(stratum[event], minlength=len(counts))
    estimate, low, high, event_ess = pooled.stratified_estimate(hits, counts, strata.masses, size, confidence)
    found = Estimate(
        "is", estimate, low, high, spend.worlds, spend.episodes, int(event.sum()), confidence, learned_worlds,
        effective_sample_size((strata.masses / counts)[stratum]), event_ess, plan=plan.as_dict(),
    )  # fmt: skip
    if target_width is not None and found.relative_half_width > target_width:
        why = "its cap of --worlds" if plan.draws >= worlds else "the pilot's plan"
        note = f"reached ±{found.relative_half_width:.0%}, short of ±{target_width:.0%}, after the {plan.draws:,} draws of {why}"
        found = Estimate(**{**asdict(found), "note": note, "plan": plan.as_dict()})
    return found


def _fall_back(
    spend: Spender, plan: pooled.Plan, config: ImportanceConfig, dim: int, worlds: int, batch: int, confidence: float, target_width: float | None,
    seen: np.ndarray, prior: Prior, seed: int, say: Say,
) -> Estimate:  # fmt: skip
    """Monte Carlo from the pilot's prior worlds when the plan says importance sampling does not pay; worlds a learned
    proposal's rounds spent are counted (they are no prior draws, so not in the estimate)."""
    say(f"{plan.fallback}: Monte Carlo instead, starting from the pilot's {config.pilot:,} prior worlds.")
    spent = spend.worlds - config.pilot
    rng = np.random.default_rng([seed, IS_STREAM, FALLBACK_DRAWS])
    found = sample_prior(spend, rng, dim, config.pilot + worlds, batch, confidence, target_width, seen, prior)
    return Estimate(**{**asdict(found), "worlds": found.worlds + spent, "search_worlds": spent, "fallback": plan.fallback, "plan": plan.as_dict()})


def _timing(timing: Mapping | None, describe: Any, episode_seconds: float, describe_seconds: float, sample: int) -> Mapping:
    """The per-world seconds the plan uses: ``timing`` when it holds a recorded plan's, else the measured ones (written
    into ``timing`` when it is an empty mutable mapping). A sample read back from a cache took no time to describe, so
    the seconds a row took when it was described stand in, and the rows the cache holds need no describing."""
    if timing:
        return timing
    kept_seconds, held = getattr(describe, "seconds_per_world", lambda: 0.0)(), getattr(describe, "held", lambda: 0)()
    measured = {"episode_seconds": episode_seconds, "describe_seconds": max(describe_seconds, kept_seconds) if describe else 0.0}
    measured["described"] = max(sample, held)
    if timing is None:
        return measured
    timing.update(measured)
    return timing


def _timed(estimate: Estimate, started: float) -> Estimate:
    return Estimate(**{**asdict(estimate), "plan": estimate.plan, "seconds": time.perf_counter() - started})


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
    check_confidence(confidence)
    if target_width is not None and not target_width > 0:
        raise WorldagentError(f"target width {target_width}; pass a positive relative half-width such as 0.5 (±50%).")
    if importance is not None:
        importance.validate()


# -- helpers ---------------------------------------------------------------------------------------


class Spender:
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


def learning_worlds(config: ImportanceConfig) -> int:
    """Worlds an importance-sampling estimate spends learning its proposal at most: the pilot, the learned proposal's
    rounds, or the search's rounds."""
    if config.proposal == "surrogate":
        return config.pilot
    if config.proposal == "learned":
        return config.pilot + learned.STAGES * round(config.pilot * learned.STAGE_SHARE)
    return config.max_rounds * config.round_worlds


def narrow_enough(hits: int, interval: tuple[float, float], estimate: float, target_width: float | None) -> bool:
    """Whether sampling may stop: a target width reached with at least ``MIN_HITS`` hits."""
    return target_width is not None and hits >= MIN_HITS and estimate > 0 and (interval[1] - interval[0]) / (2 * estimate) <= target_width


def _check_count(name: str, value: Any, cap: int = MAX_WORLDS) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise WorldagentError(f"{name}={value!r}; pass a whole number of at least 1.")
    if value > cap:
        raise WorldagentError(f"{name}={value:,} is over the cap of {cap:,}; pass a smaller number.")
