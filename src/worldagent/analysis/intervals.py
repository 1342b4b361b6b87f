"""Intervals of a probability: exact binomial ones for Monte Carlo, a weighted-hits one for importance sampling.

Every interval here lies in [0, 1] and holds its estimate (``bounded``): an importance-sampling
mean over weighted terms can pass 1 (harvest's tiny preset printed P = 1.035 outside [0.945, 1.0]).
"""

from __future__ import annotations

from statistics import NormalDist

import numpy as np

from worldagent.errors import WorldagentError


def clopper_pearson(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """The exact binomial (Clopper–Pearson) interval of a probability with k successes in n trials.

    Beta quantiles from ``scipy.stats.beta`` (scipy comes with jax).

    Returns:
        (low, high): low = 0 when k = 0, high = 1 when k = n.
    """
    from scipy.stats import beta

    if isinstance(k, bool) or isinstance(n, bool) or int(k) != k or int(n) != n or not 0 <= k <= n or n < 1:
        raise WorldagentError(f"k={k}, n={n}; pass whole numbers with 0 <= k <= n and n >= 1.")
    check_confidence(confidence)
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
    check_confidence(confidence)
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


def bounded(estimate: float, low: float, high: float) -> tuple[float, float, float]:
    """(estimate, low, high) clipped to [0, 1], with low <= estimate <= high."""
    estimate = min(max(float(estimate), 0.0), 1.0)
    return estimate, min(max(float(low), 0.0), estimate), max(min(float(high), 1.0), estimate)


def weighted_interval(terms: np.ndarray, confidence: float = 0.95, pool: int | None = None) -> tuple[float, float, float]:
    """(mean, low, high) of importance-sampling terms f64[n] = w · 1[event]: the normal interval, ``bounded``.

    Good once the event has been hit a few dozen times with weights of similar size; under
    heavy-tailed weights it is too narrow (``gamma_interval`` holds there). With ``pool`` (worlds
    drawn from a pool of that many prior worlds), the pool's binomial variance mean · (1 − mean) / pool is added.
    """
    check_confidence(confidence)
    terms = np.asarray(terms, np.float64)
    mean = float(terms.mean())
    error = float(terms.std(ddof=1) / np.sqrt(len(terms))) if len(terms) > 1 else float("inf")
    error = error if pool is None else float(np.sqrt(error**2 + min(max(mean, 0.0), 1.0) * (1 - min(max(mean, 0.0), 1.0)) / pool))
    spread = NormalDist().inv_cdf(1 - (1 - confidence) / 2) * error
    return bounded(mean, mean - spread, mean + spread)


def gamma_interval(
    weights: np.ndarray,
    counts: np.ndarray,
    confidence: float = 0.95,
    extra_variance: float = 0.0,
    unseen: bool = False,
    seen: np.ndarray | None = None,
) -> tuple[float, float]:
    """Fay & Feuer's (1997) gamma interval of y = Σ w_h x_h, a weighted sum of rare counts x_h f64[S] with weights f64[S].

    The bounds are Gamma quantiles matched to y and its variance v = Σ w_h² x_h; the upper one
    adds one more count at the largest weight of a part with hits (``unseen``: of any part, so a
    part with no hit yet widens it by a whole hit: Fay & Feuer's own, conservative choice). It is
    skewed as few unequal weighted hits are, where the normal interval is symmetric and too
    narrow below. ``extra_variance`` is added to v (a pool's own binomial variance); ``seen``
    bool[S] marks the parts with hits (None: counts > 0; a prediction from expected counts passes its own).

    Returns:
        (low, high), low = 0 when y = 0.
    """
    from scipy.stats import gamma

    check_confidence(confidence)
    weights, counts = np.asarray(weights, np.float64), np.asarray(counts, np.float64)
    tail = (1 - confidence) / 2
    seen = counts > 0 if seen is None else np.asarray(seen, bool)
    top = float(weights.max() if unseen or not seen.any() else weights[seen].max())
    y, v = float(weights @ counts), float(weights**2 @ counts) + extra_variance
    low = float(gamma.ppf(tail, y**2 / v, scale=v / y)) if y > 0 and v > 0 else y
    high = float(gamma.ppf(1 - tail, (y + top) ** 2 / (v + top**2), scale=(v + top**2) / (y + top)))
    return low, high


def check_confidence(confidence: float) -> None:
    if not 0 < confidence < 1:
        raise WorldagentError(f"confidence={confidence}; pass a level between 0 and 1, e.g. 0.95.")
