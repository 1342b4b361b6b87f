"""Importance-sampling proposals over latents: mixtures of shifted priors and kernels, and pooled weights.

Every proposal q = α N(0, I) + (1 − α) g mixes the prior p back in, so each weight p/q ≤ 1/α;
g = Σ_k share_k N(c_k, s_k² I) (``Proposal``). ``analysis.failure_rate.importance_sampling``
learns g by the cross-entropy method (``fit_mixture``: weighted EM over shifted priors, s = 1,
the number of components by BIC), then adds kernels N(z_i, h² I) around the event worlds found
(``around_hits``).

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

``Pool`` keeps every world drawn, the search's included, and weighs it by the deterministic
mixture of all the proposals used (``Pool.weights``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

MAX_CENTRES = 1000  # components of the proposal around event worlds (its cost: worlds x centres x dim)
ROWS = 2048  # latents per block when a density is evaluated: bounds the rows x components memory


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


# -- densities and draws ---------------------------------------------------------------------------


def component_logs(z: np.ndarray, proposal: Proposal) -> np.ndarray:
    """f64[n, k]: log share_k + log N(z; centre_k, scale² I) − log N(z; 0, I) for latents z f64[n, dim]."""
    norms = (z**2).sum(-1)[:, None]
    squares = np.maximum(norms - 2 * z @ proposal.centres.T + (proposal.centres**2).sum(-1)[None], 0.0)  # a matmul, not n x k x dim
    log_norm = np.log(proposal.shares) - z.shape[1] * np.log(proposal.scales)
    return log_norm[None] - squares / (2 * proposal.scales[None] ** 2) + 0.5 * norms


def log_mixture(z: np.ndarray, proposal: Proposal, skip: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """f64[n]: log g(z) − log p(z), the proposal's log density over the prior's at latents z f64[n, dim].

    ``skip``: (ids int[n] of the latents, ids int[k] of the centres): component k is left out at
    latent i where the ids match (``Pool.weights``).
    """
    blocks = []
    for start in range(0, len(z), ROWS):
        logs = component_logs(z[start : start + ROWS], proposal)
        if skip is not None:
            logs = np.where(skip[0][start : start + ROWS, None] == skip[1][None], -np.inf, logs)
        blocks.append(logsumexp(logs, axis=1))
    return np.concatenate(blocks) if blocks else np.zeros(0)


def sample_mixture(rng: np.random.Generator, proposal: Proposal, prior_weight: float, n: int) -> np.ndarray:
    """f64[n, dim] latents from q = α N(0, I) + (1 − α) g."""
    from_prior = rng.random(n) < prior_weight
    component = rng.choice(len(proposal.shares), size=n, p=proposal.shares)
    noise = rng.standard_normal((n, proposal.centres.shape[1]))
    return np.where(from_prior[:, None], noise, proposal.centres[component] + proposal.scales[component, None] * noise)


def importance_weights(z: np.ndarray, proposal: Proposal, prior_weight: float) -> np.ndarray:
    """f64[n]: p(z) / q(z) for the prior p = N(0, I) and q = α p + (1 − α) g; each at most 1/α."""
    return 1.0 / (prior_weight + (1 - prior_weight) * np.exp(np.minimum(log_mixture(z, proposal), 700.0)))


# -- fitting ---------------------------------------------------------------------------------------


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


# -- pooling every draw ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Pool:
    """Every world drawn so far, and the proposals that drew them.

    Attributes:
        z: f64[n, dim] latents.
        margin: f64[n] how far each is inside the event (> 0 inside).
        event: bool[n] which are in the event.
        drawn: (g, count) per call: count worlds drawn from α N(0, I) + (1 − α) g.
    """

    z: np.ndarray
    margin: np.ndarray
    event: np.ndarray
    drawn: tuple[tuple[Proposal, int], ...] = ()

    @classmethod
    def empty(cls, dim: int) -> Pool:
        return cls(np.zeros((0, dim)), np.zeros(0), np.zeros(0, bool))

    def add(self, z: np.ndarray, margin: np.ndarray, event: np.ndarray, proposal: Proposal) -> Pool:
        stack = np.concatenate
        return Pool(np.vstack([self.z, z]), stack([self.margin, margin]), stack([self.event, event]), (*self.drawn, (proposal, len(z))))

    def average(self) -> Proposal:
        """ḡ = Σ_r (n_r / n) g_r, identical components merged (a kernel reused by many batches costs once)."""
        centres = np.vstack([g.centres for g, _ in self.drawn])
        scales = np.concatenate([g.scales for g, _ in self.drawn])
        shares = np.concatenate([g.shares * count for g, count in self.drawn]) / len(self.z)
        rows, inverse = np.unique(np.column_stack([centres, scales]), axis=0, return_inverse=True)
        shares = np.bincount(inverse.ravel(), weights=shares)
        return Proposal(rows[shares > 0, :-1], shares[shares > 0], rows[shares > 0, -1])

    def weights(self, prior_weight: float) -> np.ndarray:
        """f64[n]: p(z) / q̄(z), q̄ = α p + (1 − α) ḡ the average of the proposals used (each at most 1/α).

        The deterministic-mixture (balance-heuristic) weights of multiple importance sampling:
        a world drawn by an early, poor proposal where a later one concentrates gets the small
        weight the later one would give it, so the search's rounds add to the estimate instead
        of widening it. A kernel centred on a world is left out of that world's own q̄: it spikes
        there (by (1/h)^dim), and kept in, it shrank the weights of exactly the event worlds (the
        toy z0 > 3: estimates at 0.6 P, intervals missing it). The proposals fitted after a world
        was drawn still depend on it a little (adaptive multiple importance sampling, Cornuet et
        al. 2012), so the mean is consistent, not exactly unbiased.
        """
        average = self.average()
        ids = np.unique(np.vstack([self.z, average.centres]), axis=0, return_inverse=True)[1].ravel()
        log_g = log_mixture(self.z, average, skip=(ids[: len(self.z)], ids[len(self.z) :]))
        return 1.0 / (prior_weight + (1 - prior_weight) * np.exp(np.minimum(log_g, 700.0)))
