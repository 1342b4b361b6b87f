"""Mixtures of isotropic Gaussians over latents: the cross-entropy search's proposals (``failure_rate``).

A proposal g = Σ_k share_k N(centre_k, scale_k² I) is mixed with the prior, q = α N(0, I) +
(1 − α) g, so that every importance weight p/q ≤ 1/α. Fitted by weighted EM (shifted priors,
the number of components by BIC) or built as kernels around the event worlds found.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

MAX_CENTRES = 1000  # components of the proposal around event worlds (its cost: worlds x centres x dim)


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


def effective_sample_size(weights: np.ndarray) -> float:
    """(Σw)² / Σw² of weights f64[n] (Kish); 0 when all are 0."""
    weights = np.asarray(weights, np.float64)
    total = float(np.sum(weights**2))
    return float(np.sum(weights) ** 2 / total) if total > 0 else 0.0


def fit_mixture(z: np.ndarray, weights: np.ndarray, components: int, rng: np.random.Generator) -> Proposal:
    """The cross-entropy update in the family of mixtures of shifted priors: weighted EM on elites z f64[m, dim]
    (weights f64[m] = p/q), for 1 to ``components`` components, keeping the fit with the lowest BIC."""
    weights = weights / weights.sum() if weights.sum() > 0 else np.full(len(z), 1 / len(z))
    count = effective_sample_size(weights)  # the elites' worth in equally weighted points: BIC's sample size
    best, best_bic = None, np.inf
    for k in range(1, min(components, len(z)) + 1):
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
