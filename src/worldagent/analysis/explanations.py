"""Why a world fails: the nearest passing world, and groups of failures (issue 15, item 3).

- ``boundary``: from a failing latent toward a passing one, the last failing and first passing
  points of the segment, found by a batched bisection (each round evaluates ``points`` evenly
  spaced latents inside the current bracket, so a round is one evaluator call). The two worlds,
  drawn side by side, show a person what changed between failing and passing.
- ``nearest``: the passing latent closest to a failing one (the segment's other end).
- ``clusters``: the failing worlds grouped by k-means on their standardised descriptors and
  latents, with a count and a representative (the member closest to its group's centre).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from worldagent.errors import WorldagentError


@dataclass(frozen=True)
class Boundary:
    """A failing latent and a passing one on the segment between two latents.

    Attributes:
        failing: f64[dim] the last failing point found (the segment's start if none later fails).
        passing: f64[dim] the first passing point found after it.
        t_failing, t_passing: their places on the segment (0: the failing end, 1: the passing end).
        evaluated: latents evaluated to find them.
    """

    failing: np.ndarray
    passing: np.ndarray
    t_failing: float
    t_passing: float
    evaluated: int


def boundary(fails: Callable[[np.ndarray], np.ndarray], z_fail: np.ndarray, z_pass: np.ndarray, rounds: int = 3, points: int = 7) -> Boundary:
    """Bisect the segment z_fail → z_pass for where failing turns into passing.

    Args:
        fails: ``latents f64[n, dim] -> bool[n]`` (one evaluator call per round).
        z_fail, z_pass: the ends: a failing and a passing latent (not re-evaluated).
        rounds: bisection rounds; the bracket shrinks by ``points + 1`` each round.
        points: latents evaluated per round.
    """
    z_fail, z_pass = np.asarray(z_fail, np.float64), np.asarray(z_pass, np.float64)
    if rounds < 1 or points < 1:
        raise WorldagentError(f"rounds={rounds}, points={points}; both must be at least 1.")
    low, high, evaluated = 0.0, 1.0, 0
    for _ in range(rounds):
        ts = np.linspace(low, high, points + 2)[1:-1]
        failing = np.asarray(fails(z_fail + ts[:, None] * (z_pass - z_fail)), bool)
        evaluated += len(ts)
        passes = np.flatnonzero(~failing)
        first_pass = int(passes[0]) if len(passes) else len(ts)  # every point before it fails
        if first_pass < len(ts):
            high = float(ts[first_pass])
        if first_pass > 0:
            low = float(ts[first_pass - 1])
    return Boundary(z_fail + low * (z_pass - z_fail), z_fail + high * (z_pass - z_fail), low, high, evaluated)


def nearest(z: np.ndarray, candidates: np.ndarray) -> int:
    """Index of the row of ``candidates [n, dim]`` nearest to ``z [dim]`` (Euclidean)."""
    candidates = np.asarray(candidates, np.float64)
    if not len(candidates):
        raise WorldagentError("no passing world to compare with; evaluate more worlds (a larger --budget).")
    return int(np.argmin(np.linalg.norm(candidates - np.asarray(z, np.float64)[None], axis=1)))


@dataclass(frozen=True)
class Cluster:
    """A group of failing worlds: ``members`` (indices into the worlds given), its ``representative``
    (the member nearest the centre) and the members' mean descriptors ``centre``."""

    members: np.ndarray
    representative: int
    centre: np.ndarray


def clusters(measures: np.ndarray, latents: np.ndarray, count: int = 4, seed: int = 0) -> list[Cluster]:
    """Up to ``count`` groups of the failing worlds (rows of ``measures [n, k]`` and ``latents [n, dim]``), largest first."""
    from sklearn.cluster import KMeans

    measures, latents = np.asarray(measures, np.float64), np.asarray(latents, np.float64)
    if not len(measures):
        return []
    features = np.concatenate([_standardised(measures), _standardised(latents) / np.sqrt(latents.shape[1])], axis=1)
    groups = min(count, len(np.unique(features, axis=0)))
    labels = KMeans(n_clusters=groups, n_init=10, random_state=seed).fit_predict(features) if groups > 1 else np.zeros(len(features), int)
    found = []
    for label in range(groups):
        members = np.flatnonzero(labels == label)
        centre = features[members].mean(axis=0)
        representative = int(members[np.argmin(np.linalg.norm(features[members] - centre, axis=1))])
        found.append(Cluster(members, representative, measures[members].mean(axis=0)))
    return sorted(found, key=lambda c: -len(c.members))


def _standardised(values: np.ndarray) -> np.ndarray:
    spread = values.std(axis=0)
    return (values - values.mean(axis=0)) / np.where(spread > 0, spread, 1.0)
