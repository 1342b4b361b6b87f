"""What the explorer's views show, as pure functions of stored evaluations and latents.

Nothing here touches a file, a network or JAX: the map's projection, the metrics a map can be
coloured by, a failure's likelihood under the prior and its severity, its nearest passing
world, and the atlas's grid of cells. ``session.py`` feeds them what ``runs.Run`` reads.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from worldagent.events import Selection, world_means


@dataclass(frozen=True)
class Projection:
    """A linear 2-D view of the latent space (the first two principal axes of the stored latents).

    Attributes:
        centre: f64[d] the stored latents' mean.
        axes: f64[2, d] unit directions; a latent z lands at ``(z - centre) @ axes.T``.
        explained: f64[2] the share of the latents' variance along each axis (what the map's axis labels say).
    """

    centre: np.ndarray
    axes: np.ndarray
    explained: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))

    def __call__(self, latents: np.ndarray) -> np.ndarray:
        return (np.asarray(latents, np.float64) - self.centre) @ self.axes.T


def principal_projection(latents: np.ndarray) -> Projection:
    """PCA of ``latents`` f[n, d] (n ≥ 1): a deterministic sign (each axis's largest entry positive)."""
    latents = np.asarray(latents, np.float64)
    dim = latents.shape[1]
    centre = latents.mean(axis=0)
    if len(latents) < 2:
        return Projection(centre, np.eye(2, dim))
    _, singular, rows = np.linalg.svd(latents - centre, full_matrices=False)
    variance = singular**2
    explained = np.zeros(2)
    explained[: min(2, len(variance))] = variance[:2] / variance.sum() if variance.sum() > 0 else 0.0
    axes = np.zeros((2, dim))
    axes[: min(2, len(rows))] = rows[:2]
    for i in range(2):
        if not axes[i].any():  # one latent dimension only, or all latents on a line
            axes[i, i % dim] = 1.0
        axes[i] *= np.sign(axes[i][np.argmax(np.abs(axes[i]))])
    return Projection(centre, axes, explained)


def scalar_metrics(evaluations: Sequence, names: Sequence[str]) -> list[str]:
    """Those of ``names`` every episode holds as one number (per-agent lists cannot colour a map)."""

    def scalar(name: str) -> bool:
        return all(name in e and isinstance(e[name], (int, float)) for ev in evaluations for e in ev.episodes)

    return [name for name in names if evaluations and scalar(name)]


def metric_table(evaluations: Sequence, names: Sequence[str]) -> dict[str, np.ndarray]:
    """{metric: f64[n]} each world's mean over its episodes."""
    return {name: world_means(evaluations, name) for name in names}


def log_prior(latents: np.ndarray) -> np.ndarray:
    """f64[n]: log N(z; 0, I) of each latent (higher: a world G(z) is likelier to be drawn)."""
    latents = np.asarray(latents, np.float64)
    return -0.5 * (latents**2).sum(axis=-1) - 0.5 * latents.shape[-1] * np.log(2 * np.pi)


def severity(selection: Selection, means: dict[str, np.ndarray]) -> np.ndarray:
    """f64[n]: how far each world lies past the selection's thresholds (sum over its one-sided clauses).

    ``crash_rate > 0.5`` at a crash rate of 0.9 is 0.4; ``group_reward < 50`` at 10 is 40. Clauses
    without a side (``==``, ``!=``) add nothing.
    """
    total = np.zeros(len(next(iter(means.values()))) if means else 0)
    for clause in selection.clauses:
        values = means[clause.metric or clause.name]
        if clause.op in ("<", "<="):
            total += clause.number - values
        elif clause.op in (">", ">="):
            total += values - clause.number
    return total


def thresholds(selection: Selection, names: Sequence[str]) -> dict[str, dict]:
    """{metric: {"op", "value"}} of the selection's one-sided clauses on ``names``: where a map's diverging
    colour scale turns from passing to failing."""
    found = {}
    for clause in selection.clauses:
        metric = clause.metric or clause.name
        if metric in names and clause.op in ("<", "<=", ">", ">="):
            found.setdefault(metric, {"op": clause.op, "value": float(clause.number)})
    return found


# The map's campaign markers: each shape filled, then each hollow (a campaign's marker stays one of these).
# plots.js's drawShape draws each name.
MARKER_SHAPES = ("circle", "square", "triangle", "diamond", "down", "plus", "star", "hexagon", "left", "cross", "right")
MARKERS = tuple({"shape": shape, "filled": filled} for filled in (True, False) for shape in MARKER_SHAPES)


def campaign_markers(count: int) -> list[dict]:
    """The map marker ({"shape", "filled"}) of each of ``count`` campaigns, in order: all distinct up to
    ``len(MARKERS)`` (22) campaigns; past that they start over (campaign 23 looks like campaign 1: the map's
    legend says so, and a campaign's worlds are told apart by hiding the others)."""
    return [MARKERS[c % len(MARKERS)] for c in range(count)]


def worse_ends(selection: Selection | None, atlases: Sequence[tuple[str, bool]], names: Sequence[str]) -> dict[str, str]:
    """{metric: "low" | "high"}: which end of each of ``names`` is the worse one, where the run says: the side
    the failure event ``selection`` selects (``crash_rate > 0.5``: high), else the side a failure atlas
    searched for (``atlases``: (metric, maximize) of each; minimised: low). Metrics it says nothing of are left out.

    The explorer paints the worse end yellow (viridis's bright end), as the report's atlas figure does
    (``reports/atlas.py``: viridis_r when the atlas minimised).
    """
    found: dict[str, str] = {}
    for clause in selection.clauses if selection is not None else ():
        metric = clause.metric or clause.name
        if metric in names and clause.op in ("<", "<=", ">", ">="):
            found.setdefault(metric, "low" if clause.op[0] == "<" else "high")
    for metric, maximize in atlases:
        if metric in names:
            found.setdefault(metric, "high" if maximize else "low")
    return found


def nearest(latents: np.ndarray, candidates: np.ndarray, beyond: float = -1.0) -> tuple[np.ndarray, np.ndarray]:
    """(index into ``candidates`` f[m, d], distance) of the nearest candidate farther than ``beyond``
    from each latent f[n, d]; (-1, inf) where there is none."""
    if len(candidates) == 0 or len(latents) == 0:
        return np.full(len(latents), -1), np.full(len(latents), np.inf)
    distances = np.linalg.norm(np.asarray(latents)[:, None, :] - np.asarray(candidates)[None, :, :], axis=-1)
    distances = np.where(distances > beyond, distances, np.inf)
    found = distances.argmin(axis=1)
    closest = distances[np.arange(len(latents)), found]
    return np.where(np.isfinite(closest), found, -1), closest


def rank_failures(latents: np.ndarray, failing: np.ndarray, severities: np.ndarray, by: str) -> np.ndarray:
    """Indices of the failing worlds (bool[n] ``failing``), likeliest under the prior first
    (``by="likelihood"``) or the most severe first (``by="severity"``); ties keep store order."""
    index = np.flatnonzero(failing)
    key = log_prior(latents[index]) if by == "likelihood" else severities[index]
    return index[np.argsort(-key, kind="stable")]


def distinct_worlds(keys: Sequence[str], order: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the first of ``order`` for each distinct world, how many of ``order`` share it), in ``order``'s order;
    ``keys[k]`` is the identity of ``order[k]``'s repaired world (``store.world_digest``).

    A world evaluated again (importance sampling draws from a pool; campaigns meet; latents that repair to one world) is one world.
    """
    first: dict[str, int] = {}
    counts: dict[str, int] = {}
    for i, key in zip(order, keys, strict=True):
        first.setdefault(key, int(i))
        counts[key] = counts.get(key, 0) + 1
    return np.array(list(first.values()), int), np.array([counts[key] for key in first], int)


def atlas_cells(cells: Sequence[int], grid_cells: Sequence[int], scores: np.ndarray, maximize: bool) -> list[dict]:
    """The atlas as a 2-D heat map: each filled cell's (column, row) on the first two descriptors.

    Descriptors beyond the second are folded: a map cell keeps its worst world over them (the
    lowest score, or the highest when the atlas maximised). Returns one dict per map cell:
    ``{"x", "y", "score", "entry"}``, ``entry`` indexing ``cells``/``scores``.
    """
    shape = tuple(grid_cells) if len(grid_cells) >= 2 else (*tuple(grid_cells), 1)
    best: dict[tuple[int, int], int] = {}
    for entry, cell in enumerate(cells):
        position = np.unravel_index(int(cell), shape)
        key = (int(position[0]), int(position[1]))
        held = best.get(key)
        worse = held is None or (scores[entry] > scores[held] if maximize else scores[entry] < scores[held])
        if worse:
            best[key] = entry
    return [{"x": x, "y": y, "score": float(scores[entry]), "entry": entry} for (x, y), entry in sorted(best.items())]
