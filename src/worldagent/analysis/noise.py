"""The world's share of an episode's outcome (DESIGN.md "Noise: the world's share and confirmation").

An episode's outcome is world plus dice: the same world played again gives another return. With
every world played ``k`` times (``values[worlds, k]``), a one-way random-effects analysis of
variance splits the outcome's variance into a part between worlds and a part within them:

- **ICC(1)** (Shrout & Fleiss 1979, case 1; McGraw & Wong 1996): the share of one episode's
  variance that belongs to the world (truncated at 0), with a 95% percentile-bootstrap interval over
  worlds (the F interval assumes normal outcomes, which crash penalties are not). When the world explains
  10%, a search over worlds mostly finds luck; the fix is more episodes per world, not more worlds.
- **Reliability** of a world's score at ``k`` episodes, ICC(1, k) = k·ICC / (1 + (k-1)·ICC)
  (Spearman–Brown): the correlation between two independent k-episode scores of the same worlds.
- **Failing episodes on failing worlds**: of all failing episodes, the share on worlds that fail
  at least half the time. Low means failures are spread thin over many worlds (dice), high means
  they concentrate on worlds that fail (the world).

For a binary event (an episode fails or not) the same estimator is the ANOVA estimator of the
intra-class correlation of binary outcomes (Ridout, Demétrio & Firth 1999 compare it with others).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

CONFIDENCE = 0.95
BOOTSTRAP = 2000  # resamples of the worlds for the share's interval


@dataclass(frozen=True)
class WorldShare:
    """How much of a metric's episode-to-episode variance belongs to the world.

    Attributes:
        icc: ICC(1), the share of one episode's variance between worlds (NaN: no variance at all).
        low, high: its 95% interval (percentile bootstrap over worlds).
        reliability: ICC(1, k) of a world's mean over ``repeats`` episodes.
        reliability_low, reliability_high: its 95% interval.
        worlds: worlds counted (those with ``repeats`` finite values).
        repeats: episodes per world.
    """

    icc: float
    low: float
    high: float
    reliability: float
    reliability_low: float
    reliability_high: float
    worlds: int
    repeats: int

    def as_dict(self) -> dict:
        return {key: (value if not isinstance(value, float) or np.isfinite(value) else None) for key, value in asdict(self).items()}


def _mean_squares(means: np.ndarray, variances: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(between, within) mean squares of a one-way ANOVA from each world's mean and variance (last axis: worlds)."""
    return k * means.var(axis=-1, ddof=1), variances.mean(axis=-1)


def _icc(between, within, k: int):
    """ICC(1) and ICC(1, k) from mean squares, truncated at 0 (a share of variance is not negative)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        icc = (between - within) / (between + (k - 1) * within)
        reliability = (between - within) / between
    return np.clip(np.nan_to_num(icc, nan=0.0), 0, 1), np.clip(np.nan_to_num(reliability, nan=0.0), 0, 1)


def world_share(values: np.ndarray, confidence: float = CONFIDENCE, resamples: int = BOOTSTRAP) -> WorldShare:
    """ICC(1) and the reliability of a ``k``-episode score from ``values`` f64[worlds, k] (k >= 2).

    The interval is a percentile bootstrap over worlds (``resamples`` draws, a fixed seed): the exact F
    interval assumes normal outcomes, and racing's rare crashes (returns near -280 among returns near 60)
    make it far too narrow. Worlds with a non-finite value are left out. All values equal: NaN (nothing to
    share). No variance within worlds but some between: 1 (the world is everything).
    """
    values = np.asarray(values, np.float64)
    if values.ndim != 2 or values.shape[1] < 2:
        raise ValueError(f"values must be [worlds, repeats >= 2]; got shape {values.shape}")
    values = values[np.isfinite(values).all(axis=1)]
    n, k = values.shape
    nan = float("nan")
    if n < 2:
        return WorldShare(nan, nan, nan, nan, nan, nan, n, k)
    means, variances = values.mean(axis=1), values.var(axis=1, ddof=1)
    between, within = _mean_squares(means, variances, k)
    if between <= 0 and within <= 0:
        return WorldShare(nan, nan, nan, nan, nan, nan, n, k)
    if within <= 0:
        return WorldShare(1.0, 1.0, 1.0, 1.0, 1.0, 1.0, n, k)
    icc, reliability = _icc(between, within, k)
    picks = np.random.default_rng(0).integers(0, n, size=(resamples, n))
    boot_icc, boot_reliability = _icc(*_mean_squares(means[picks], variances[picks], k), k)
    tails = [100 * (1 - confidence) / 2, 100 * (1 + confidence) / 2]
    low, high = np.percentile(boot_icc, tails)
    r_low, r_high = np.percentile(boot_reliability, tails)
    return WorldShare(float(icc), float(low), float(high), float(reliability), float(r_low), float(r_high), n, k)


def spearman_brown(icc: float, repeats: int) -> float:
    """The reliability of a mean over ``repeats`` episodes when one episode's is ``icc``."""
    return repeats * icc / (1 + (repeats - 1) * icc)


def repeats_for(icc: float, reliability: float = 0.8) -> int | None:
    """Episodes per world for a score of the given reliability (None when the world explains nothing)."""
    if not np.isfinite(icc) or icc <= 0:
        return None
    if icc >= 1:
        return 1
    return int(np.ceil(reliability * (1 - icc) / (icc * (1 - reliability)) - 1e-9))  # 36.0000001 is 36


def failing_on_failing_worlds(fails: np.ndarray) -> float:
    """Of all failing episodes (``fails`` bool[worlds, k]), the share on worlds that fail in at least half of theirs."""
    fails = np.asarray(fails, bool)
    total = fails.sum()
    if total == 0:
        return float("nan")
    mostly = fails.mean(axis=1) >= 0.5
    return float(fails[mostly].sum() / total)


def episode_values(evaluations: Sequence, metric: str) -> np.ndarray:
    """f64[worlds, k]: ``metric`` of every episode of each evaluation (NaN where missing); [0, 0] when the
    evaluations hold different numbers of episodes or none."""
    counts = {len(e.episodes) for e in evaluations}
    if len(counts) != 1 or 0 in counts:
        return np.zeros((0, 0))
    value = lambda episode: np.nan if episode.get(metric) is None else float(np.mean(episode[metric]))  # noqa: E731
    return np.array([[value(episode) for episode in e.episodes] for e in evaluations], np.float64)


def episode_failures(evaluations: Sequence, selection) -> np.ndarray:
    """bool[worlds, k]: which single episodes satisfy ``selection`` (each clause on that episode's value)."""
    columns = [(clause, episode_values(evaluations, clause.metric)) for clause in selection.clauses]
    if not columns or columns[0][1].size == 0:
        return np.zeros((0, 0), bool)
    shape = columns[0][1].shape
    return np.logical_and.reduce([clause.holds(values.ravel()).reshape(shape) for clause, values in columns])


def noise_summary(evaluations: Sequence, metrics: Sequence[str], failure=None) -> dict:
    """The world's share of each metric (and of the failure event, given a parsed selection) over stored evaluations.

    Returns:
        {"worlds", "repeats", "metrics": {name: WorldShare.as_dict()}, and with ``failure``: "failure": {"event",
        "share": ..., "episodes_failing", "on_failing_worlds"}}; {} when fewer than 2 episodes per world.
    """
    repeats = {len(e.episodes) for e in evaluations}
    if len(repeats) != 1 or min(repeats) < 2 or len(evaluations) < 2:
        return {}
    summary: dict = {"worlds": len(evaluations), "repeats": repeats.pop(), "metrics": {}}
    for metric in metrics:
        values = episode_values(evaluations, metric)
        if values.size and np.isfinite(values).any():
            summary["metrics"][metric] = world_share(values).as_dict()
    if failure is not None:
        fails = episode_failures(evaluations, failure)
        if fails.size:
            summary["failure"] = {
                "event": failure.describe(),
                "share": world_share(fails.astype(np.float64)).as_dict(),
                "episodes_failing": float(fails.mean()),
                "on_failing_worlds": failing_on_failing_worlds(fails),
            }
    return summary


def _pct(value) -> str:
    return "n/a" if value is None or not np.isfinite(value) else f"{value:.2f}"


def share_line(summary: dict, metric: str) -> str:
    """One line: "world's share of return 0.10 [0.07, 0.14], reliability at 8 episodes 0.46; crashed (…) 0.09 […];
    failing episodes on worlds failing >= half: 7%"."""
    if not summary:
        return ""
    parts = []
    share = summary["metrics"].get(metric)
    if share:
        parts.append(
            f"world's share of {metric} {_pct(share['icc'])} [{_pct(share['low'])}, {_pct(share['high'])}], "
            f"reliability at {summary['repeats']} episodes {_pct(share['reliability'])}"
        )
    failure = summary.get("failure")
    if failure:
        fshare = failure["share"]
        on = failure["on_failing_worlds"]
        parts.append(
            f"of the failure ({failure['event']}) {_pct(fshare['icc'])} [{_pct(fshare['low'])}, {_pct(fshare['high'])}]"
            + ("" if on is None or not np.isfinite(on) else f"; failing episodes on worlds failing >= half: {on:.0%}")
        )
    if share and share["icc"] is not None and np.isfinite(share["icc"]) and share["icc"] < 0.25:
        more = repeats_for(share["icc"])
        parts.append("mostly dice: a search over worlds finds luck" + (f"; {more} episodes per world give reliability 0.8" if more else ""))
    return "; ".join(parts)
