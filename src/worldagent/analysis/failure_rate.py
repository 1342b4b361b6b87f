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

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from statistics import NormalDist
from typing import Any

import numpy as np
from scipy.special import logsumexp

from worldagent.errors import WorldagentError
from worldagent.evaluation.backends import LocalBackend, split
from worldagent.search.campaign import REPLAY_TOLERANCE, evaluation_seed
from worldagent.store import Campaign, RunStore

METHODS = ("mc", "is")
BATCH = 1000  # worlds per call of evaluate (a generation of the store campaign)
MC_STREAM, IS_STREAM = 2, 3  # latent streams default_rng([seed, stream]): not random search's (1)
MIN_HITS = 10  # events seen before a target width may stop sampling (the intervals are poor below)
MAX_CENTRES = 1000  # components of the proposal around event worlds (its cost: worlds x centres x dim)


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
    """

    round_worlds: int = 500
    max_rounds: int = 10
    elite_fraction: float = 0.1
    prior_weight: float = 0.1
    components: int = 8
    bandwidth: float | None = 0.7
    wide_share: float = 0.3

    def validate(self) -> None:
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


@dataclass(frozen=True)
class Hits:
    """Event worlds found so far: z f64[h, dim] and their weights p/q f64[h] under the proposal that drew them."""

    z: np.ndarray
    weights: np.ndarray

    def add(self, z: np.ndarray, weights: np.ndarray) -> Hits:
        return Hits(np.vstack([self.z, z]), np.concatenate([self.weights, weights]))


@dataclass(frozen=True)
class Proposal:
    """g = Σ_k share_k N(centre_k, scale_k² I) over latents.

    Attributes:
        centres: f64[k, dim].
        shares: f64[k], summing to 1.
        scales: f64[k], the components' standard deviations.
    """

    centres: np.ndarray
    shares: np.ndarray
    scales: np.ndarray

    @classmethod
    def shift(cls, mean: np.ndarray) -> Proposal:
        """The prior shifted to ``mean`` f64[dim]: one component of scale 1."""
        return cls(np.asarray(mean, np.float64)[None, :], np.ones(1), np.ones(1))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Proposal) and all(
            np.array_equal(getattr(self, name), getattr(other, name)) for name in ("centres", "shares", "scales")
        )


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


def effective_sample_size(weights: np.ndarray) -> float:
    """(Σw)² / Σw² of weights f64[n] (Kish); 0 when all are 0."""
    weights = np.asarray(weights, np.float64)
    total = float(np.sum(weights**2))
    return float(np.sum(weights) ** 2 / total) if total > 0 else 0.0


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
    weight, event = np.concatenate(weights), np.concatenate(events)
    if not event.any():
        hint = f"the closest came within {-best:.3g} of it: check the thresholds, or search longer (more rounds or worlds per round)"
        hint = "sample more worlds" if best >= 0 else hint
        raise WorldagentError(f"the event never occurred in the {len(event)} worlds sampled for importance sampling ({hint}).")
    estimate, low, high = weighted_interval(weight * event, confidence)
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
        proposal = fit_mixture(z[elite], weights[elite], config, rng)
        if level >= 0 and scored.event.sum() >= 2:  # fitted to the event's worlds: to the prior on it
            break
    return proposal, best, hits


def elites(scored: Scored, level: float) -> np.ndarray:
    """bool[n]: the worlds to fit: the event's once the bar reaches it, else those strictly past the bar (a tie at it,
    from a discrete metric, would stall the search), else those at it; the first choice with two worlds or more."""
    choices = ((scored.event,) if level >= 0 else ()) + (scored.margin > level,)
    return next((choice for choice in choices if choice.sum() >= 2), scored.margin >= level)


def fit_mixture(z: np.ndarray, weights: np.ndarray, config: ImportanceConfig, rng: np.random.Generator) -> Proposal:
    """The cross-entropy update in the family of mixtures of shifted priors: weighted EM on elites z f64[m, dim]
    (weights f64[m] = p/q), for 1 to ``config.components`` components, keeping the fit with the lowest BIC."""
    weights = weights / weights.sum() if weights.sum() > 0 else np.full(len(z), 1 / len(z))
    count = effective_sample_size(weights)  # the elites' worth in equally weighted points: BIC's sample size
    best, best_bic = None, np.inf
    for k in range(1, min(config.components, len(z)) + 1):
        proposal = weighted_em(z, weights, k, rng)
        bic = -2 * count * float(weights @ log_mixture(z, proposal)) + (k * (z.shape[1] + 1) - 1) * np.log(max(count, 2.0))
        if bic < best_bic:
            best, best_bic = proposal, bic
    return best


def weighted_em(z: np.ndarray, weights: np.ndarray, k: int, rng: np.random.Generator, steps: int = 30) -> Proposal:
    """k shifted priors N(c, I) fitted by EM to points z f64[m, dim] with weights f64[m] (sum 1), started from
    weighted k-means++ centres."""
    centres = z[[rng.choice(len(z), p=weights)]]
    while len(centres) < k:  # k-means++: the next centre far from the chosen ones
        far = weights * np.min(((z[:, None, :] - centres[None]) ** 2).sum(-1), axis=1)
        centres = np.vstack([centres, z[rng.choice(len(z), p=far / far.sum()) if far.sum() > 0 else rng.choice(len(z))]])
    proposal = Proposal(centres, np.full(k, 1 / k), np.ones(k))
    for _ in range(steps):
        log_parts = component_logs(z, proposal)
        resp = np.exp(log_parts - logsumexp(log_parts, axis=1, keepdims=True)) * weights[:, None]
        mass = resp.sum(axis=0)
        keep = mass > 1e-12  # an emptied component is dropped
        proposal = Proposal((resp[:, keep].T @ z) / mass[keep, None], mass[keep] / mass[keep].sum(), np.ones(int(keep.sum())))
    return proposal


def blend(wide: Proposal, narrow: Proposal, wide_share: float) -> Proposal:
    """The mixture wide_share · wide + (1 − wide_share) · narrow."""
    return Proposal(
        np.vstack([wide.centres, narrow.centres]),
        np.concatenate([wide_share * wide.shares, (1 - wide_share) * narrow.shares]),
        np.concatenate([wide.scales, narrow.scales]),
    )


def around_hits(z: np.ndarray, weights: np.ndarray, bandwidth: float, rng: np.random.Generator) -> Proposal:
    """N(z_i, bandwidth² I) around event worlds z f64[h, dim], shares ∝ their weights f64[h] = p/q: a kernel
    estimate of the prior on the event (``MAX_CENTRES`` of them at most, drawn by weight)."""
    shares = weights / weights.sum()
    if len(z) > MAX_CENTRES:
        keep = rng.choice(len(z), MAX_CENTRES, replace=False, p=shares)
        z, shares = z[keep], np.full(MAX_CENTRES, 1 / MAX_CENTRES)
    return Proposal(z, shares, np.full(len(z), bandwidth))


def component_logs(z: np.ndarray, proposal: Proposal) -> np.ndarray:
    """f64[n, k]: log share_k + log N(z; centre_k, scale² I) − log N(z; 0, I) for latents z f64[n, dim]."""
    squares = ((z[:, None, :] - proposal.centres[None]) ** 2).sum(-1)
    log_norm = np.log(proposal.shares) - z.shape[1] * np.log(proposal.scales)
    return log_norm[None] - squares / (2 * proposal.scales[None] ** 2) + 0.5 * (z**2).sum(-1)[:, None]


def log_mixture(z: np.ndarray, proposal: Proposal) -> np.ndarray:
    """f64[n]: log g(z) − log p(z), the proposal's log density over the prior's at latents z f64[n, dim]."""
    return logsumexp(component_logs(z, proposal), axis=1)


def sample_mixture(rng: np.random.Generator, proposal: Proposal, prior_weight: float, n: int) -> np.ndarray:
    """f64[n, dim] latents from q = α N(0, I) + (1 − α) g."""
    from_prior = rng.random(n) < prior_weight
    component = rng.choice(len(proposal.shares), size=n, p=proposal.shares)
    noise = rng.standard_normal((n, proposal.centres.shape[1]))
    return np.where(from_prior[:, None], noise, proposal.centres[component] + proposal.scales[component, None] * noise)


def importance_weights(z: np.ndarray, proposal: Proposal, prior_weight: float) -> np.ndarray:
    """f64[n]: p(z) / q(z) for the prior p = N(0, I) and q = α p + (1 − α) g; each at most 1/α."""
    return 1.0 / (prior_weight + (1 - prior_weight) * np.exp(np.minimum(log_mixture(z, proposal), 700.0)))


# -- evaluation through the run store --------------------------------------------------------------


def campaign_name(method: str, event: str, seed: int) -> str:
    """``failure-is-crash_rate>0.5-s0``: the store campaign of one estimate."""
    return f"failure-{method}-{''.join(event.split())}-s{seed}"


class StoredEvaluate:
    """``evaluate(z, seeds) -> Scored`` that commits every world to a store campaign and replays it on a rerun.

    Args:
        store: the run store; ``campaign``: the estimate's (``RunStore.open_campaign``).
        outcomes: ``(z, seeds) -> [Outcome]`` (``search.objectives.LatentObjective``).
        score: ``[worlds with .episodes] -> Scored`` (``score_worlds`` with the selection).
        backend: runs the batches (``evaluation.backends``; None: here).
        advance: called with the number of worlds done (a progress bar).
    """

    def __init__(
        self, store: RunStore, campaign: Campaign, outcomes: Callable, score: Callable, backend: Any = None, advance: Callable | None = None
    ):
        self.store, self.campaign, self.outcomes, self.score = store, campaign, outcomes, score
        self.backend, self.advance = backend or LocalBackend(), advance or (lambda done: None)
        self.stored: dict[int, dict] = {}
        for evaluation in store.iter_evaluations(campaign.name):
            self.stored.setdefault(evaluation.generation, {})[evaluation.slot] = evaluation
        self.generation = 0

    def __call__(self, z: np.ndarray, seeds: np.ndarray) -> Scored:
        generation, self.generation = self.generation, self.generation + 1
        done = dict(self.stored.get(generation, {}))
        if any(slot >= len(z) or not np.allclose(e.latent, z[slot], atol=REPLAY_TOLERANCE, rtol=0) for slot, e in done.items()):
            raise WorldagentError(
                f"campaign {self.campaign.name!r} in {self.store.path} holds other worlds at generation {generation} than this run asks "
                "(other settings or code); use another --out."
            )
        self.advance(len(done))
        missing = [slot for slot in range(len(z)) if slot not in done]
        started = time.time()
        for slots, outcomes in self.backend.run(self.outcomes, [(part, z[part], seeds[part]) for part in split(missing, self.backend.workers)]):
            for slot, outcome in zip(slots, outcomes):
                self.store.add(self.campaign, generation, slot, z[slot], self.score([outcome]).margin[0], outcome.episodes, started, outcome.world)
                done[slot] = outcome
            self.advance(len(slots))
        return self.score([done[slot] for slot in range(len(z))])


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
