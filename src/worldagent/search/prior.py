"""Where the generator's prior lives: its log-density, |z| against it, and the bound searches stay within (issue 48).

G(z) was trained for z ~ N(0, I) (paper §4.2): the decoder has seen latents near the prior's typical set and nowhere
else. Far outside it (CMA-ES pushing a descriptor reached |z| = 41.8 in 10 dimensions, where a prior draw has |z| of
about 3.1) G still returns a world, but one the VAE never learnt to make, and a failure found there says little about
the worlds the generator stands for. So every search reports each found world's place under the prior, and by default
stays inside the typical set.

**The typical set is a ball, |z| <= r.** Under z ~ N(0, I_d), |z|² follows χ² with d degrees of freedom, so |z|
follows the χ distribution: its mass concentrates on a thin shell (d = 10: median 3.06, 99% below 4.82). The bound
``typical_radius(d)`` is the χ distribution's ``TYPICAL_MASS`` = 99.9% quantile: d = 10 gives r = 5.44 (2: 3.72;
32: 7.90). 99.9% keeps all but one prior draw in a thousand, so the bound removes nothing a random search would
plausibly draw, while the log-density at the edge (d = 10: 9.9 nats below the prior's mean log-density) is still that of
latents the decoder saw in training. Why not a box |z_i| <= 3 (the optimisers' old setting)? A box bounds each
coordinate, not the prior's density: in 10 dimensions its corners reach |z| = 9.5 (a χ₁₀ tail of 5e-15, further out than
any prior draw), while it cuts away 2.7% of prior mass whose |z| is ordinary (one coordinate past 3σ). The density of
N(0, I) depends on |z| alone, so its level sets, and its typical set, are balls.

``within_ball`` keeps a latent inside by radial projection: z ↦ z · min(1, r / |z|), the nearest point of the ball.
A campaign applies it to every latent an optimiser asks before the latent is decoded (``optimisers.WithinPrior``), so
the stored latent is the evaluated one. Random search is exempt: it samples the prior itself.

Everything here is pure and works on f64[n, d] batches (a single latent f[d] too).
"""

from __future__ import annotations

import math

import numpy as np

from worldagent.errors import WorldagentError

TYPICAL_MASS = 0.999  # the prior mass inside the default bound (the χ_d quantile), see the module docstring
TYPICAL = "typical"  # the bound's name on the command line and in code: ``typical_radius(dim)``
BEYOND = "none"  # no bound: the search may leave the prior's typical set


def latent_norm(z) -> np.ndarray:
    """f64[n] (or a float for one latent f[d]): |z|, the Euclidean norm of each latent."""
    return np.linalg.norm(np.asarray(z, np.float64), axis=-1)


def log_prior(z) -> np.ndarray:
    """f64[n]: log N(z; 0, I), the prior's log-density at each latent (nats)."""
    z = np.asarray(z, np.float64)
    return -0.5 * np.sum(z * z, axis=-1) - 0.5 * z.shape[-1] * math.log(2.0 * math.pi)


def typical_log_prior(dim: int) -> float:
    """E[log N(z; 0, I)] under the prior: the log-density a typical draw has, -d/2 (1 + log 2π)."""
    return -0.5 * dim * (1.0 + math.log(2.0 * math.pi))


def norm_percentile(norm, dim: int) -> np.ndarray:
    """P(|z'| <= norm) for z' ~ N(0, I_dim): where |z| lies among the prior's draws (χ²_dim CDF of norm²), in [0, 1]."""
    from scipy.stats import chi2

    return chi2.cdf(np.square(np.asarray(norm, np.float64)), dim)


def norm_tail_log10(norm, dim: int) -> np.ndarray:
    """log10 P(|z'| >= norm) under the prior: how far out a latent is when its percentile rounds to 100%.

    Where the χ² tail underflows (|z| beyond ~38 in 10 dimensions), its leading asymptotic term: the upper incomplete
    gamma Q(a, x) ~ x^(a-1) e^(-x) / Γ(a) (1 + (a-1)/x), a = d/2, x = |z|²/2.
    """
    from scipy.special import gammaln
    from scipy.stats import chi2

    squared = np.square(np.asarray(norm, np.float64))
    exact = chi2.logsf(squared, dim)
    a, x = 0.5 * dim, np.maximum(0.5 * squared, 1.0)
    asymptotic = (a - 1) * np.log(x) - x - gammaln(a) + np.log1p((a - 1) / x)
    return np.where(np.isfinite(exact), exact, asymptotic) / math.log(10.0)


def typical_radius(dim: int, mass: float = TYPICAL_MASS) -> float:
    """The radius of the ball holding ``mass`` of N(0, I_dim): the χ_dim quantile (dim 10, 99.9%: 5.44)."""
    from scipy.stats import chi2

    if dim < 1 or not 0.0 < mass < 1.0:
        raise WorldagentError(f"typical_radius(dim={dim}, mass={mass}): pass a positive dimension and a mass in (0, 1).")
    return float(math.sqrt(chi2.ppf(mass, dim)))


def within_ball(z, radius: float | None) -> np.ndarray:
    """f64[n, d]: each latent projected radially onto the ball |z| <= ``radius`` (unchanged inside it; None: no bound)."""
    z = np.asarray(z, np.float64)
    if radius is None:
        return z.copy()
    norm = latent_norm(z)[..., None]
    return np.where(norm > radius, z * (radius / np.where(norm > radius, norm, 1.0)), z)


def prior_bound(value, dim: int) -> float | None:
    """The radius a bound names: ``TYPICAL`` (the default: ``typical_radius(dim)``), ``BEYOND``/None (no bound), or a
    positive radius (a number or its text, as ``--prior-bound`` takes it). Bad values are refused in one line."""
    if value is None or (isinstance(value, str) and value.strip().lower() == BEYOND):
        return None
    if isinstance(value, str) and value.strip().lower() == TYPICAL:
        return typical_radius(dim)
    try:
        radius = float(value)
    except (TypeError, ValueError):
        radius = float("nan")
    if not (math.isfinite(radius) and radius > 0):
        raise WorldagentError(f"--prior-bound {value!r}: pass {TYPICAL} (the prior's 99.9% ball), {BEYOND} (search beyond it), or a radius > 0.")
    return radius


def prior_summary(z) -> dict:
    """Where one latent f[d] lies under the prior, for JSON: its norm, log-density, the prior's typical log-density,
    the percentile of |z| among prior draws, its log10 tail probability, and whether it is inside the typical set."""
    z = np.asarray(z, np.float64).reshape(-1)
    dim, norm = z.size, float(latent_norm(z))
    return {
        "dim": dim,
        "norm": norm,
        "log_prior": float(log_prior(z)),
        "typical_log_prior": typical_log_prior(dim),
        "percentile": float(norm_percentile(norm, dim)),
        "tail_log10": float(norm_tail_log10(norm, dim)),
        "typical_radius": typical_radius(dim),
        "in_typical_set": bool(norm <= typical_radius(dim) * (1 + 1e-9)),
    }


def prior_text(z) -> str:
    """ "|z| 3.41 (72nd percentile of the prior's; log-prior -14.1, typical -14.2)": one latent f[d] in words;
    beyond the 99.99th percentile the tail probability instead ("|z| 41.8 (P(|z'| >= |z|) = 1e-369 under the prior...")."""
    return summary_text(prior_summary(z)) if np.size(z) else "no latent"


def summary_text(found: dict) -> str:
    """``prior_text`` of a ``prior_summary`` (as a JSON result holds it)."""
    if found["percentile"] <= 0.9999:
        where = f"{ordinal(100 * found['percentile'])} percentile of the prior's"
    else:
        where = f"P(|z'| >= |z|) = 1e{found['tail_log10']:.0f} under the prior"
    outside = "" if found["in_typical_set"] else f", outside the typical set |z| <= {found['typical_radius']:.2f}"
    return f"|z| {found['norm']:.3g} ({where}; log-prior {found['log_prior']:.1f}, typical {found['typical_log_prior']:.1f}{outside})"


def ordinal(percent: float) -> str:
    """``72nd``, ``1st``, ``99.3th``, ``99.95th``: a percentile in words (rounded down: one decimal above 99, two above 99.9)."""
    if percent > 99.0:
        places = 2 if percent > 99.9 else 1
        return f"{math.floor(percent * 10**places) / 10**places:g}th"
    n = int(round(percent))
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def bound_text(radius: float | None, dim: int) -> str:
    """ "within the prior's typical set |z| <= 5.44 (99.9% of its mass)" or "beyond the prior (no bound on |z|)"."""
    if radius is None:
        return "beyond the prior (no bound on |z|)"
    mass = float(norm_percentile(radius, dim))
    return f"within |z| <= {radius:.3g} ({ordinal(100 * mass)} percentile of the prior's |z|)"


def norms_summary(latents) -> dict:
    """Where many found latents f[n, d] lie under the prior (an atlas's elites), for JSON: how many, the median and
    largest |z|, the largest one's percentile, and how many lie outside the typical set."""
    latents = np.asarray(latents, np.float64)
    if latents.ndim != 2 or not latents.size:
        return {"count": 0}
    norms, dim = latent_norm(latents), latents.shape[1]
    return {
        "count": int(len(norms)),
        "median_norm": float(np.median(norms)),
        "max_norm": float(norms.max()),
        "max_percentile": float(norm_percentile(norms.max(), dim)),
        "typical_radius": typical_radius(dim),
        "outside_typical_set": int(np.sum(norms > typical_radius(dim) * (1 + 1e-9))),
    }


def norms_text(found: dict) -> str:
    """ "|z| median 3.1, max 5.44 (99.9th percentile of the prior's); 0 of 87 outside the typical set |z| <= 5.44"."""
    if not found.get("count"):
        return "no latents"
    return (
        f"|z| median {found['median_norm']:.3g}, max {found['max_norm']:.3g} ({ordinal(100 * found['max_percentile'])} percentile of the "
        f"prior's); {found['outside_typical_set']} of {found['count']} outside the typical set |z| <= {found['typical_radius']:.3g}"
    )
