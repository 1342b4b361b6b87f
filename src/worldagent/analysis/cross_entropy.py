"""Importance sampling from a proposal learned by the cross-entropy method: ``ImportanceConfig.proposal = "search"``.

The older proposal, kept beside the pooled one (``analysis.pooled``), in two stages:

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
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from worldagent.analysis.failure_rate import IS_STREAM, Estimate, Evaluate, ImportanceConfig, Scored, Spender, narrow_enough
from worldagent.analysis.intervals import weighted_interval
from worldagent.analysis.mixtures import Hits, Proposal, around_hits, blend, effective_sample_size, fit_mixture, importance_weights, sample_mixture
from worldagent.errors import WorldagentError


def search_sampling(
    evaluate: Evaluate, dim: int, worlds: int, *, config: ImportanceConfig, seed: int = 0, batch: int = 1000, confidence: float = 0.95,
    target_width: float | None = None,
) -> Estimate:  # fmt: skip
    """P(event) by importance sampling from a proposal learned by the cross-entropy method (module docstring).

    The interval is the normal one on the weighted mean (``weighted_interval``), kept in [0, 1].
    """
    rng = np.random.default_rng([seed, IS_STREAM])
    spend = Spender(evaluate, seed)
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
        if narrow_enough(int(np.sum(np.concatenate(events))), weighted_interval(terms, confidence)[1:], float(terms.mean()), target_width):
            break
    return weighted_estimate(np.concatenate(weights), np.concatenate(events), spend, search_worlds, best, confidence)


def weighted_estimate(weight: np.ndarray, event: np.ndarray, spend: Spender, search_worlds: int, best: float, confidence: float) -> Estimate:
    """The search's ``Estimate`` from the sampled worlds' weights f64[n] and events bool[n]."""
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
        proposal = fit_mixture(z[elite], weights[elite], config.components, rng)
        if level >= 0 and scored.event.sum() >= 2:  # fitted to the event's worlds: to the prior on it
            break
    return proposal, best, hits


def elites(scored: Scored, level: float) -> np.ndarray:
    """bool[n]: the worlds to fit: the event's once the bar reaches it, else those strictly past the bar (a tie at it,
    from a discrete metric, would stall the search), else those at it; the first choice with two worlds or more."""
    choices = ((scored.event,) if level >= 0 else ()) + (scored.margin > level,)
    return next((choice for choice in choices if choice.sum() >= 2), scored.margin >= level)
