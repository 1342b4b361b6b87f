"""Two agents compared world by world (DESIGN.md "Diff"): paired statistics over per-world metrics.

Agents A (the old one) and B (the new one) play the same W worlds with the same episode keys
(common random numbers), so each world gives a pair and every statistic here is paired: the
world is the unit, its R episodes are averaged first. All functions are pure and take arrays
``[W, R]`` (or per-world means ``[W]``) of A and B.

- ``paired_difference``: the mean of B − A per world with Hall's (1992) skewness-corrected t
  interval over worlds (a collapse of B on a few worlds skews the differences; the plain t interval
  then covered 92.5% at 30 worlds, Hall's 94.0%, ``benchmarks/diff_coverage.py``).
- ``paired_failures``: P(failure) of each (Clopper–Pearson), the paired difference with Tango's
  score interval (1998; its statistic at 0 is McNemar's, so it excludes 0 exactly when the
  score test rejects), the exact conditional McNemar p-value, and the counts of worlds that
  regressed (fail under B, pass under A) and improved.
- ``paired_cvar``: the α-CVaR (mean of the worst α of worlds, SFL's robustness protocol) of each
  and their difference, with a BCa bootstrap over worlds (pairs resampled together), and a one-line
  warning when the tail holds fewer than ``MIN_TAIL_WORLDS`` worlds: no interval from a small tail
  can know a failure rarer than the tail shows (racing, a crash on 0.7% of worlds: 58% coverage at
  10 tail worlds, 77% at 20, 92% at 40, 96% at 100; ``benchmarks/results/diff-coverage-cpu.json``).
- ``regressed_ranking``: the regressed worlds, likeliest under the prior N(0, I) first, each with
  its nearest world (by latent, else by any feature) where B passes.

Identical agents give differences of exactly 0 (the t and bootstrap intervals collapse to [0, 0]).
"""

from __future__ import annotations

import math

import numpy as np

from worldagent.analysis.intervals import check_confidence, clopper_pearson

CVAR_ALPHA = 0.1  # the worst 10% of worlds
BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_CHUNK = 100  # resamples drawn at once (memory: CHUNK x W indices)
MIN_TAIL_WORLDS = 100  # fewer tail worlds and the α-CVaR interval is flagged (coverage measured above; see paired_cvar)
SAME_POINT = 1e-9  # a world this close to a regressed one is the same world, never its own neighbour


def world_means(values) -> np.ndarray:
    """f64[W]: per-world means of ``values`` f[W, R] (episodes averaged), or ``values`` f[W] as is."""
    values = np.asarray(values, np.float64)
    return values.reshape(len(values), -1).mean(axis=1) if values.ndim > 1 else values


def paired_difference(a, b, confidence: float = 0.95) -> dict:
    """The mean over worlds of B − A with Hall's skewness-corrected t interval over the W paired worlds.

    Args:
        a, b: f[W, R] (or f[W]) one metric of A and of B on the same worlds and keys.
        confidence: the interval's level.

    Returns:
        {"a", "b": the means over worlds, "difference": mean of B − A, "low", "high": its interval
        (``hall_interval``; NaN with one world; [d, d] when every world differs by the same d), "worlds": W}.
    """
    check_confidence(confidence)
    a, b = world_means(a), world_means(b)
    differences = b - a
    count = len(differences)
    mean = float(differences.mean()) if count else float("nan")
    low, high = hall_interval(differences, confidence) if count >= 2 else (float("nan"), float("nan"))
    return {"a": float(a.mean()), "b": float(b.mean()), "difference": mean, "low": low, "high": high, "worlds": count}


def hall_interval(values, confidence: float = 0.95) -> tuple[float, float]:
    """Hall's (1992) skewness-corrected t interval of the mean of ``values`` f[n] (n ≥ 2).

    The studentised mean T = (x̄ − μ)/(s/√n) of skewed values is skewed too; Hall's cubic
    g(T) = T + γT²/(3√n) + γ²T³/(27n) + γ/(6√n) (γ: the values' skewness) removes the first-order
    skew, is monotone, and inverts in closed form: μ ∈ [x̄ − s/√n · g⁻¹(q), x̄ − s/√n · g⁻¹(−q)] with q
    the t quantile. With γ = 0 it is the t interval; with s = 0, [x̄, x̄].
    """
    from scipy.stats import t

    values = np.asarray(values, np.float64)
    count, mean, sd = len(values), float(values.mean()), float(values.std(ddof=1))
    if not sd > 0:
        return mean, mean
    q, root, error = float(t.ppf(1 - (1 - confidence) / 2, count - 1)), math.sqrt(count), sd / math.sqrt(count)
    skew = float(np.mean((values - mean) ** 3)) / sd**3
    if abs(skew) < 1e-12:
        return mean - q * error, mean + q * error
    inverse = lambda x: 3 * root / skew * (np.cbrt(1 + skew * (x - skew / (6 * root)) / root) - 1)  # noqa: E731
    return mean - error * float(inverse(q)), mean - error * float(inverse(-q))


def _tango_statistic(regressed: int, improved: int, n: int, delta: float) -> float:
    """Tango's score statistic for H0: p_B − p_A = ``delta`` (decreasing in ``delta``)."""
    a = 2.0 * n
    b = -regressed - improved + (2.0 * n - regressed + improved) * delta
    c = -improved * delta * (1.0 - delta)
    p_improved = (math.sqrt(max(b * b - 4.0 * a * c, 0.0)) - b) / (2.0 * a)  # restricted MLE of P(A fails, B passes)
    variance = n * (2.0 * p_improved + delta * (1.0 - delta))
    return (regressed - improved - n * delta) / math.sqrt(max(variance, 1e-300))


def tango_interval(regressed: int, improved: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Tango's (1998) score interval of p_B − p_A from paired binary outcomes.

    Args:
        regressed: worlds where B fails and A passes; ``improved``: A fails and B passes.
        n: worlds compared (concordant ones included).

    Returns:
        (low, high) within [−1, 1]; a non-degenerate interval about 0 when no world is discordant.
    """
    from scipy.optimize import brentq
    from scipy.stats import norm

    check_confidence(confidence)
    if n < 1 or regressed < 0 or improved < 0 or regressed + improved > n:
        raise ValueError(f"regressed={regressed}, improved={improved}, n={n}; need 0 <= regressed + improved <= n, n >= 1.")
    z = float(norm.ppf(1 - (1 - confidence) / 2))
    estimate = (regressed - improved) / n
    edge = 1.0 - 1e-12
    score = lambda delta, target: _tango_statistic(regressed, improved, n, delta) - target  # noqa: E731
    low = -1.0 if score(-edge, z) <= 0 else brentq(score, -edge, estimate, args=(z,), xtol=1e-12)
    high = 1.0 if score(edge, -z) >= 0 else brentq(score, estimate, edge, args=(-z,), xtol=1e-12)
    return float(low), float(high)


def mcnemar_p(regressed: int, improved: int) -> float:
    """The exact conditional (McNemar) two-sided p-value of p_B = p_A: a binomial test of the
    discordant worlds, regressed ~ Binomial(regressed + improved, 1/2); 1 when none is discordant."""
    from scipy.stats import binom

    discordant = regressed + improved
    if discordant == 0:
        return 1.0
    return float(min(1.0, 2.0 * binom.cdf(min(regressed, improved), discordant, 0.5)))


def paired_failures(fail_a, fail_b, confidence: float = 0.95) -> dict:
    """P(failure) of each agent and their paired difference.

    Args:
        fail_a, fail_b: bool[W] which worlds fail under A and under B (the same worlds).

    Returns:
        {"a", "b": {"p", "low", "high", "failing"} (Clopper–Pearson), "difference": {"value"
        (p_B − p_A), "low", "high" (Tango), "p_value" (exact McNemar)}, "regressed", "improved",
        "worlds"}.
    """
    fail_a, fail_b = np.asarray(fail_a, bool), np.asarray(fail_b, bool)
    if fail_a.shape != fail_b.shape or fail_a.ndim != 1 or not len(fail_a):
        raise ValueError(f"fail_a {fail_a.shape} and fail_b {fail_b.shape}: pass two bool[W] of the same worlds, W >= 1.")
    n = len(fail_a)
    regressed, improved = int(np.sum(fail_b & ~fail_a)), int(np.sum(fail_a & ~fail_b))

    def rate(fails: np.ndarray) -> dict:
        k = int(fails.sum())
        low, high = clopper_pearson(k, n, confidence)
        return {"p": k / n, "low": low, "high": high, "failing": k}

    low, high = tango_interval(regressed, improved, n, confidence)
    difference = {"value": (regressed - improved) / n, "low": low, "high": high, "p_value": mcnemar_p(regressed, improved)}
    return {"a": rate(fail_a), "b": rate(fail_b), "difference": difference, "regressed": regressed, "improved": improved, "worlds": n}


def tail_count(worlds: int, alpha: float) -> int:
    """How many worlds the α-tail holds: ⌈α · W⌉, at least one."""
    if not 0 < alpha <= 1:
        raise ValueError(f"alpha={alpha}; pass a fraction in (0, 1], e.g. 0.1.")
    return max(1, math.ceil(alpha * worlds - 1e-9))


def cvar(values, alpha: float = CVAR_ALPHA, axis: int = -1) -> np.ndarray:
    """α-CVaR: the mean of the lowest ⌈α · W⌉ per-world values along ``axis`` (higher is better)."""
    values = np.asarray(values, np.float64)
    k = tail_count(values.shape[axis], alpha)
    return np.partition(values, k - 1, axis=axis).take(np.arange(k), axis=axis).mean(axis=axis)


def paired_cvar(a, b, alpha: float = CVAR_ALPHA, confidence: float = 0.95, resamples: int = BOOTSTRAP_RESAMPLES, seed: int = 0) -> dict:
    """α-CVaR of A and of B over the same worlds and its paired difference, bootstrapped over worlds.

    Each resample draws W worlds with replacement and takes both agents' values on them, so the
    pairing (and the common random numbers) carries into the interval.

    Args:
        a, b: f[W, R] (or f[W]) a metric where higher is better (e.g. the return).
        alpha: the tail's share of worlds.
        resamples: bootstrap resamples; ``seed`` their randomness.

    Returns:
        {"alpha", "a", "b", "difference" (CVaR_B − CVaR_A), "low", "high" (BCa interval), "tail": worlds
        in the tail, "warning": ``tail_warning``'s line, or None with ``MIN_TAIL_WORLDS`` or more}.
    """
    check_confidence(confidence)
    a, b = world_means(a), world_means(b)
    rng = np.random.default_rng([seed, 40])
    differences = []
    for start in range(0, resamples, BOOTSTRAP_CHUNK):
        picks = rng.integers(0, len(a), (min(BOOTSTRAP_CHUNK, resamples - start), len(a)))
        differences.append(cvar(b[picks], alpha) - cvar(a[picks], alpha))
    cvar_a, cvar_b = float(cvar(a, alpha)), float(cvar(b, alpha))
    resampled = np.concatenate(differences) if differences else np.zeros(0)
    low, high = bca_interval(resampled, cvar_b - cvar_a, jackknife_cvar(a, b, alpha), confidence)
    tail = tail_count(len(a), alpha)
    return {
        "alpha": alpha,
        "a": cvar_a,
        "b": cvar_b,
        "difference": cvar_b - cvar_a,
        "low": low,
        "high": high,
        "tail": tail,
        "warning": tail_warning(tail, alpha),
    }


def tail_warning(tail: int, alpha: float) -> str | None:
    """One line when an α-CVaR interval rests on fewer than ``MIN_TAIL_WORLDS`` tail worlds, naming the fix; else None.

    The line holds no env's figures (it is printed for every env): it gives the chance, exact for any env, that the
    worlds compared hold none of a failure on 1% of worlds, which no interval over them can then see."""
    if tail >= MIN_TAIL_WORLDS:
        return None
    worlds = max(1, round(tail / alpha))
    return (
        f"the α-CVaR interval rests on {tail} tail worlds (< {MIN_TAIL_WORLDS}): a failure too rare to reach the tail may be missing from it "
        f"({worlds} worlds hold none of a failure on 1% of worlds {miss_chance(0.01, worlds):.0%} of the time); read it loosely, "
        f"or pass --worlds {math.ceil(MIN_TAIL_WORLDS / alpha)} or more."
    )


def miss_chance(share: float, worlds: int) -> float:
    """The chance that ``worlds`` independent worlds hold none of a failure on ``share`` of worlds: (1 − share)^worlds."""
    return (1.0 - share) ** worlds


def worlds_to_catch(share: float, power: float = 0.95, at_least: int = 1) -> int:
    """How many random worlds hold at least ``at_least`` of a blind spot on ``share`` of worlds with probability ``power``.

    For one world it is ⌈ln(1 − power) / ln(1 − share)⌉; for more, the smallest n with P(Binomial(n, share) ≥ at_least)
    ≥ power. A gate that fires on ``at_least`` regressed worlds needs this many worlds to catch the blind spot that often,
    assuming every sampled world of the blind spot counts as regressed (B fails it, A passes it).
    """
    from scipy.stats import binom

    if not 0 < share < 1 or not 0 < power < 1 or at_least < 1:
        raise ValueError(f"share={share}, power={power}, at_least={at_least}; pass a share and a power in (0, 1) and at_least >= 1.")
    low = math.ceil(math.log(1 - power) / math.log(1 - share) - 1e-9)  # enough for one; more need more worlds
    if at_least == 1:
        return low
    caught = lambda n: binom.sf(at_least - 1, n, share) >= power  # noqa: E731
    high = low
    while not caught(high):
        high *= 2
    while low < high:  # the smallest n that catches it (P grows with n)
        middle = (low + high) // 2
        low, high = (middle + 1, high) if not caught(middle) else (low, middle)
    return high


def regressed_to_reject(worlds: int, confidence: float = 0.95) -> int:
    """The fewest regressed worlds (none improved) for which Tango's interval of p_B − p_A excludes 0
    (the gate ``p_failure_increase_low > 0``): 4 at 95%, whatever the number of ``worlds``."""
    return next(r for r in range(1, worlds + 1) if tango_interval(r, 0, worlds, confidence)[0] > 0)


def blind_spot_table(shares=(0.01, 0.003, 0.001), power: float = 0.95, at=(500, 1000)) -> list[dict]:
    """Per blind-spot share, the worlds a gate needs to catch it with probability ``power``: one regressed world
    (``regressed > 0``), enough for Tango's interval to exclude 0 (``p_failure_increase_low > 0``), and six
    (``regressed > 5``); and the chance each gate catches it on each number of worlds in ``at``."""
    from scipy.stats import binom

    needed = {"regressed > 0": 1, "p_failure_increase_low > 0": regressed_to_reject(max(at)), "regressed > 5": 6}
    return [
        {
            "share": share,
            "worlds_needed": {gate: worlds_to_catch(share, power, count) for gate, count in needed.items()},
            "caught": {worlds: {gate: float(binom.sf(count - 1, worlds, share)) for gate, count in needed.items()} for worlds in at},
        }
        for share in shares
    ]


def interval_test_disagreement(difference: dict, discordant: int, confidence: float = 0.95) -> str | None:
    """One line when Tango's interval of p_B − p_A and the exact McNemar test disagree on whether it is 0; else None.

    Tango's score interval is a large-sample one; the exact test is exact but conservative. With few discordant worlds
    (those where only one agent fails) the interval can exclude 0 while p > 1 − confidence (4 worlds regressed and none
    improved: the interval excludes 0, p = 0.125), or, more rarely, the other way round.

    Args:
        difference: ``paired_failures``'s "difference" ({"low", "high", "p_value"}).
        discordant: worlds where exactly one agent fails (regressed + improved).
    """
    excludes = difference["low"] > 0 or difference["high"] < 0
    rejects = difference["p_value"] < 1 - confidence
    if excludes == rejects:
        return None
    said = "excludes 0 but the exact McNemar test does not reject" if excludes else "holds 0 but the exact McNemar test rejects"
    return (
        f"Tango's interval {said} (p = {difference['p_value']:.3g}): they disagree when few worlds are discordant ({discordant} here), "
        "where the interval's large-sample score is approximate and the exact test conservative; read the change as borderline, "
        "or compare on more worlds."
    )


def leave_one_out_cvar(values: np.ndarray, alpha: float) -> np.ndarray:
    """f64[W]: the α-CVaR of ``values`` f[W] with each world left out in turn, from one sort (W ≥ 2)."""
    k = tail_count(len(values) - 1, alpha)
    rank = np.empty(len(values), int)
    rank[np.argsort(values, kind="stable")] = np.arange(len(values))
    sums = np.concatenate([[0.0], np.cumsum(np.sort(values))])
    return np.where(rank < k, (sums[k + 1] - values) / k, sums[k] / k)  # a tail world out: the next one comes in


def jackknife_cvar(a: np.ndarray, b: np.ndarray, alpha: float) -> np.ndarray:
    """f64[W]: CVaR_B − CVaR_A with each world left out in turn (BCa's acceleration; empty for one world)."""
    if len(a) < 2:
        return np.zeros(0)
    return leave_one_out_cvar(b, alpha) - leave_one_out_cvar(a, alpha)


def bca_interval(resampled: np.ndarray, estimate: float, jackknife: np.ndarray, confidence: float) -> tuple[float, float]:
    """Efron's bias-corrected and accelerated bootstrap interval from resampled statistics f64[B].

    A tail mean is skewed and biased in small samples; BCa corrects both (on skewed returns at 100
    worlds, percentile intervals covered 91% and BCa 93%, ``benchmarks/diff_coverage.py``). Ties with
    the estimate count half (identical agents: every resample is 0, and so is the interval).
    """
    from scipy.stats import norm

    if not len(resampled):
        return float("nan"), float("nan")
    below = np.mean(resampled < estimate) + 0.5 * np.mean(resampled == estimate)
    bias = float(norm.ppf(np.clip(below, 1e-6, 1 - 1e-6)))
    spread = jackknife.mean() - jackknife if len(jackknife) else np.zeros(1)
    denominator = 6.0 * float(np.sum(spread**2)) ** 1.5
    acceleration = float(np.sum(spread**3)) / denominator if denominator > 0 else 0.0
    z = norm.ppf([(1 - confidence) / 2, 1 - (1 - confidence) / 2])
    levels = norm.cdf(bias + (bias + z) / (1 - acceleration * (bias + z)))
    low, high = np.quantile(resampled, levels)
    return float(low), float(high)


def log_prior(latents) -> np.ndarray:
    """f64[n]: log N(z; 0, I) of latents f[n, d] (higher: G(z) is likelier to be drawn)."""
    latents = np.asarray(latents, np.float64)
    return -0.5 * (latents**2).sum(axis=-1) - 0.5 * latents.shape[-1] * np.log(2 * np.pi)


def nearest(points, candidates) -> tuple[np.ndarray, np.ndarray]:
    """(index into ``candidates`` f[m, d], distance) of the nearest candidate to each point f[n, d]
    that is not the point itself (farther than ``SAME_POINT``); (-1, inf) where there is none."""
    points, candidates = np.asarray(points, np.float64), np.asarray(candidates, np.float64)
    if not len(points) or not len(candidates):
        return np.full(len(points), -1), np.full(len(points), np.inf)
    distances = np.linalg.norm(points[:, None, :] - candidates[None, :, :], axis=-1)
    distances = np.where(distances > SAME_POINT, distances, np.inf)
    found = distances.argmin(axis=1)
    closest = distances[np.arange(len(points)), found]
    return np.where(np.isfinite(closest), found, -1), closest


def regressed_ranking(fail_a, fail_b, features, latents=None) -> list[dict]:
    """The regressed worlds (B fails, A passes), each with its nearest world where B passes.

    Args:
        fail_a, fail_b: bool[W] which worlds fail under A and under B.
        features: f[W, d] where worlds lie, for the nearest passing world (latents, or e.g. a world's cells).
        latents: f[W, dim] the worlds' latents, or None (worlds not drawn from G(z)).

    Returns:
        [{"world": index, "log_prior" (None without latents), "nearest_passing": index or None,
        "distance"}], likeliest under N(0, I) first when there are latents, else in world order.
    """
    fail_a, fail_b = np.asarray(fail_a, bool), np.asarray(fail_b, bool)
    regressed = np.flatnonzero(fail_b & ~fail_a)
    prior = log_prior(latents)[regressed] if latents is not None else np.zeros(len(regressed))
    order = regressed[np.argsort(-prior, kind="stable")]
    prior = prior[np.argsort(-prior, kind="stable")]
    passing = np.flatnonzero(~fail_b)
    features = np.asarray(features, np.float64).reshape(len(fail_a), -1)
    near, distance = nearest(features[order], features[passing])
    return [
        {
            "world": int(world),
            "log_prior": float(prior[k]) if latents is not None else None,
            "nearest_passing": int(passing[near[k]]) if near[k] >= 0 else None,
            "distance": float(distance[k]) if near[k] >= 0 else None,
        }
        for k, world in enumerate(order)
    ]


def pooled_difference(arm, base, statistic, confidence: float = 0.95, resamples: int = BOOTSTRAP_RESAMPLES, seed: int = 0) -> dict:
    """An arm against a base arm, pooled over training seeds and paired by world: a hierarchical bootstrap.

    Benchmarks train S agents per arm and let every agent play the same W worlds with the same
    episode keys. Seeds are independent runs (seed s of one arm is no pair of seed s of another),
    worlds are shared. Each resample draws W worlds with replacement, the same for both arms (the
    pairing by world and keys carries into the interval), and each arm's seeds with replacement,
    independently; ``statistic`` of the arm minus that of the base gives one difference, and the
    percentile interval of the resamples is returned. Why a bootstrap and not a mixed model: it
    needs no model of how worlds and seeds interact, and the statistics (a CVaR, a failure share)
    are not means a linear model would fit.

    Args:
        arm, base: f[S, W] per-world values (episodes averaged) of each arm's S agents (S may differ).
        statistic: ``values f[S, W] -> float`` (e.g. the mean over seeds of each seed's α-CVaR).
        resamples: bootstrap resamples; ``seed`` their randomness.

    Returns:
        {"arm", "base": the statistic of each, "difference": arm − base, "low", "high", "seeds": [S_arm, S_base], "worlds": W}.
    """
    check_confidence(confidence)
    arm, base = np.asarray(arm, np.float64), np.asarray(base, np.float64)
    if arm.ndim != 2 or base.ndim != 2 or arm.shape[1] != base.shape[1]:
        raise ValueError(f"arm {arm.shape} and base {base.shape}: pass f[S, W] each, on the same W worlds.")
    rng = np.random.default_rng([seed, 41])
    worlds = arm.shape[1]
    differences = np.empty(resamples)
    for i in range(resamples):
        picked = rng.integers(0, worlds, worlds)
        ours = arm[rng.integers(0, len(arm), len(arm))][:, picked]
        theirs = base[rng.integers(0, len(base), len(base))][:, picked]
        differences[i] = statistic(ours) - statistic(theirs)
    tail = (1 - confidence) / 2
    low, high = (float(q) for q in np.quantile(differences, [tail, 1 - tail])) if resamples else (float("nan"),) * 2
    estimate_arm, estimate_base = float(statistic(arm)), float(statistic(base))
    return {
        "arm": estimate_arm,
        "base": estimate_base,
        "difference": estimate_arm - estimate_base,
        "low": low,
        "high": high,
        "seeds": [len(arm), len(base)],
        "worlds": worlds,
    }
