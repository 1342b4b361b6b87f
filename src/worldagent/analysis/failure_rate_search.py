"""The search of importance sampling: the cross-entropy method over mixtures of shifted priors and kernels.

``learn_proposal`` is stage 1 of ``analysis.failure_rate.importance_sampling`` (that module's
docstring has the method; ``analysis.proposals`` the families and the pooled weights).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from worldagent.analysis.proposals import Pool, Proposal, around_hits, blend, fit_mixture, importance_weights, sample_mixture
from worldagent.errors import WorldagentError

if TYPE_CHECKING:  # failure_rate imports this module
    from worldagent.analysis.failure_rate import Scored


@dataclass(frozen=True)
class ImportanceConfig:
    """Settings of ``importance_sampling``.

    Attributes:
        round_worlds: worlds per cross-entropy round.
        max_rounds: rounds at most (the search stops once the elites are all in the event, or
            ``search_hits`` event worlds have been found).
        elite_fraction: the top fraction of a round the proposal is fitted to.
        prior_weight: α, the prior's share of the mixture (weights ≤ 1/α).
        components: shifted priors in the search's proposal at most (1: a single mean shift);
            the number is chosen per round by BIC on the weighted elites.
        bandwidth: after the search, the proposal is N(z_i, bandwidth² I) around every event
            world z_i found so far, weighted by p/q, refitted after each batch (at most 1; None:
            keep the search's mixture of shifted priors).
        wide_share: the search's mixture's share of g beside the kernels: it keeps sampling around
            the regions the search found, where kernels may not reach yet.
        search_hits: event worlds found (over all rounds) that end the search early (None: never);
            it takes effect only with kernels (``bandwidth``).
    """

    round_worlds: int = 500
    max_rounds: int = 10
    elite_fraction: float = 0.1
    prior_weight: float = 0.1
    components: int = 8
    bandwidth: float | None = 0.7
    wide_share: float = 0.3
    search_hits: int | None = 20

    def validate(self) -> None:
        _check_count("round_worlds", self.round_worlds)
        _check_count("max_rounds", self.max_rounds)
        _check_count("components", self.components)
        if self.search_hits is not None:
            _check_count("search_hits", self.search_hits)
        if not 0 <= self.wide_share < 1:
            raise WorldagentError(f"wide_share={self.wide_share}; pass a fraction in [0, 1).")
        for name in ("elite_fraction", "prior_weight"):
            if not 0 < getattr(self, name) < 1:
                raise WorldagentError(f"{name}={getattr(self, name)}; pass a fraction between 0 and 1.")
        if self.bandwidth is not None and not 0 < self.bandwidth <= 1:
            raise WorldagentError(f"bandwidth={self.bandwidth}; pass a standard deviation in (0, 1], or None for the search's mixture.")
        if self.round_worlds * self.elite_fraction < 2:
            raise WorldagentError(f"{self.round_worlds} worlds per round keep fewer than 2 elites; raise round_worlds or elite_fraction.")


def learn_proposal(
    spend: Callable[[np.ndarray], Scored],
    rng: np.random.Generator,
    dim: int,
    config: ImportanceConfig,
    done: Callable[[Pool, np.ndarray], bool] = lambda pool, weights: False,
) -> tuple[Proposal, float, Pool]:
    """The cross-entropy method: (the search's mixture, the best margin seen, every world drawn); ``spend(z) -> Scored``
    evaluates; ``done(pool, pooled weights)`` ends the search once the pooled estimate is narrow enough."""
    proposal, best, pool = Proposal.shift(np.zeros(dim)), -np.inf, Pool.empty(dim)
    enough = config.search_hits if config.bandwidth is not None and config.search_hits is not None else np.inf
    for _ in range(config.max_rounds):
        z = sample_mixture(rng, proposal, config.prior_weight, config.round_worlds)
        scored = spend(z)
        pool = pool.add(z, scored.margin, scored.event, proposal)
        finite = scored.margin[np.isfinite(scored.margin)]
        if finite.size == 0:
            raise WorldagentError("the event's metrics are NaN on every world of a search round; check the policy and the metrics.")
        best = max(best, float(finite.max()))
        level = min(0.0, float(np.quantile(finite, 1 - config.elite_fraction)))  # never past the event itself
        elite, weights = elites(scored.margin, scored.event, level), importance_weights(z, proposal, config.prior_weight)
        proposal = wide = fit_mixture(z[elite], weights[elite], config.components, rng)
        pooled = pool.weights(config.prior_weight)
        if config.bandwidth is not None:  # kernels around every pooled world past the bar climb into cells shifts miss
            past = elites(pool.margin, pool.event, level)
            proposal = blend(wide, around_hits(pool.z[past], pooled[past], config.bandwidth, rng), config.wide_share)
        if (level >= 0 and scored.event.sum() >= 2) or pool.event.sum() >= enough or done(pool, pooled):
            break  # at the event's prior, or enough hits for the kernels to take over, or narrow already
    return wide, best, pool


def elites(margin: np.ndarray, event: np.ndarray, level: float) -> np.ndarray:
    """bool[n]: of worlds with margins f64[n] and events bool[n], those to fit: the event's once the bar reaches it, else those strictly past the bar (a tie at it,
    from a discrete metric, would stall the search), else those at it; the first choice with two worlds or more."""
    choices = ((event,) if level >= 0 else ()) + (margin > level,)
    return next((choice for choice in choices if choice.sum() >= 2), margin >= level)


def _check_count(name: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise WorldagentError(f"{name}={value!r}; pass a whole number of at least 1.")
