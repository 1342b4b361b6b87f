"""The numbers an influencing run reports: per-world episode values, means over seeds with a 95% interval."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np


def episode_values(evaluations: Sequence, metric: str) -> np.ndarray:
    """f64[worlds, repeats] of one metric from a campaign's evaluations (NaN where it is missing)."""
    return np.asarray([[float(np.nan if e.get(metric) is None else e[metric]) for e in ev.episodes] for ev in evaluations], np.float64)


def mean_and_ci(values: Sequence[float], level: float = 0.95) -> dict:
    """Mean over seeds and the half-width of its Student-t confidence interval (NaN with one seed:
    one seed says nothing about the spread between seeds)."""
    values = np.asarray(values, np.float64)
    n = len(values)
    if n < 2:
        return {"mean": float(values.mean()) if n else float("nan"), "ci95": float("nan"), "seeds": n}
    from scipy.stats import t  # scipy comes with bayesian-optimization (scikit-learn)

    half = float(t.ppf(0.5 + level / 2, n - 1) * values.std(ddof=1) / np.sqrt(n))
    return {"mean": float(values.mean()), "ci95": half, "seeds": n}


def summarise(per_seed: dict[str, dict[str, dict[str, float]]], metrics: Sequence[str]) -> dict:
    """{metric: {label: mean_and_ci over seeds}} from {label: {seed: {metric: value}}}."""
    return {m: {label: mean_and_ci([row[m] for row in runs.values()]) for label, runs in per_seed.items()} for m in metrics}


def json_safe(value: Any) -> Any:
    """NaN and infinities as null (strict JSON), recursively."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def rounded(value: Any, digits: int = 3) -> Any:
    """Every number of a nested dict rounded (timings in the result file)."""
    if isinstance(value, dict):
        return {k: rounded(v, digits) for k, v in value.items()}
    return round(float(value), digits)
