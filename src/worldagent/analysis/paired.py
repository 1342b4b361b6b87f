"""Paired evaluations read back: the statistics of ``analysis.diff`` over a diff campaign's evaluations.

A paired evaluation (``differential.PairedObjective``) holds, per episode, B's metrics under their
names and A's under ``A.<name>`` (``BASELINE``). ``summarise`` gives what ``worldagent diff``
reports about a world set; ``search_summary`` what a differential search found. Both read only
evaluations (and, for worlds without latents, the store), never an agent.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from worldagent.analysis import diff as stats
from worldagent.envs.registry import EnvSpec
from worldagent.errors import WorldagentError
from worldagent.store import Evaluation, RunStore

BASELINE = "A."  # prefix of A's metrics in a paired evaluation's episodes


def paired_metrics(evaluations: list[Evaluation], names: tuple[str, ...]) -> tuple[dict, dict]:
    """({metric: f64[W, R]} of A, the same of B) for each scalar metric of ``names`` every episode holds."""
    a, b = {}, {}
    for name in names:
        try:
            values_b = np.array([[e[name] for e in ev.episodes] for ev in evaluations], np.float64)
            values_a = np.array([[e[BASELINE + name] for e in ev.episodes] for ev in evaluations], np.float64)
        except (KeyError, TypeError, ValueError):  # a per-agent metric (lists), or one an episode lacks
            continue
        if values_a.ndim == 2 and values_a.shape == values_b.shape:
            a[name], b[name] = values_a, values_b
    return a, b


def failing(selection: Any, means: dict[str, np.ndarray]) -> np.ndarray:
    """bool[W]: the worlds whose per-world means ``means`` {metric: f64[W]} satisfy the (resolved) selection."""
    count = len(next(iter(means.values())))
    keep = np.ones(count, bool)
    for clause in selection.clauses:
        metric = clause.metric or clause.name
        if metric not in means:
            raise WorldagentError(f"the failure reads {metric!r}, which these episodes lack; use one of: {', '.join(means)}.")
        keep &= clause.holds(means[metric])
    return keep


def failure_masks(evaluations: list[Evaluation], spec: EnvSpec, selection: Any) -> tuple[np.ndarray, np.ndarray, dict, dict]:
    """(bool[W] A fails, bool[W] B fails, A's {metric: f64[W, R]}, B's) of a paired campaign's evaluations."""
    a, b = paired_metrics(evaluations, spec.metrics.names)
    if not a:
        raise WorldagentError("these evaluations hold no paired episodes (A.<metric> beside each metric); pass a diff campaign.")
    means_a = {name: stats.world_means(v) for name, v in a.items()}
    means_b = {name: stats.world_means(v) for name, v in b.items()}
    return failing(selection, means_a), failing(selection, means_b), a, b


def world_ref(evaluation: Evaluation) -> dict:
    """Where a world is stored: {"campaign", "generation", "slot"}."""
    return {"campaign": evaluation.campaign, "generation": evaluation.generation, "slot": evaluation.slot}


def features_of(evaluations: list[Evaluation], spec: EnvSpec, store: RunStore | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """(f64[W, d] where each world lies, latents f64[W, dim] or None): the latents, else the worlds' cells."""
    if evaluations and all(len(e.latent) for e in evaluations):
        latents = np.stack([e.latent for e in evaluations]).astype(np.float64)
        return latents, latents
    if store is None:
        raise WorldagentError("worlds without latents need their store to be placed (their cells); pass the store.")
    worlds = spec.stack_worlds([store.world(e.campaign, e.generation, e.slot) for e in evaluations])
    return np.asarray(spec.cells(worlds), np.float64), None


def regressed_rows(evaluations, fail_a, fail_b, features, latents, shown: dict[str, tuple[np.ndarray, np.ndarray]], limit: int) -> list[dict]:
    """The regressed worlds (``analysis.diff.regressed_ranking``) as JSON rows: where each is stored,
    its ``shown`` metrics {metric: (A f64[W], B f64[W])}, and its nearest world where B passes."""
    rows = []
    for row in stats.regressed_ranking(fail_a, fail_b, features, latents)[:limit]:
        i, near = row["world"], row["nearest_passing"]
        rows.append(
            {
                **world_ref(evaluations[i]),
                "log_prior": row["log_prior"],
                "a": {name: float(values[0][i]) for name, values in shown.items()},
                "b": {name: float(values[1][i]) for name, values in shown.items()},
                "nearest_passing": None if near is None else {**world_ref(evaluations[near]), "distance": row["distance"]},
            }
        )
    return rows


def summarise(
    evaluations: list[Evaluation],
    spec: EnvSpec,
    selection: Any,
    metric: str,
    *,
    store: RunStore | None = None,
    alpha: float = stats.CVAR_ALPHA,
    seed: int = 0,
    limit: int = 20,
) -> dict:
    """The paired comparison over a world set's evaluations (a paired campaign).

    Args:
        evaluations: the paired campaign's evaluations (``prior_set`` / ``fixed_set``).
        spec: the env; ``selection``: the failure (``events.parse_selection``, resolved for the env).
        metric: canonical metric of the α-CVaR (higher is better, e.g. the return).
        store: the run store (for worlds without latents, placed by their cells).
        alpha: the CVaR's tail; ``seed``: the bootstrap's; ``limit``: regressed worlds listed.

    Returns:
        {"worlds": W, "repeats": R, "episodes": 2·W·R, "metrics": {metric: ``paired_difference``},
        "failure": ``paired_failures`` with "event", "cvar": ``paired_cvar`` with "metric",
        "regressed_worlds": rows (``regressed_rows``)}.
    """
    fail_a, fail_b, a, b = failure_masks(evaluations, spec, selection)
    features, latents = features_of(evaluations, spec, store)
    repeats = int(next(iter(a.values())).shape[1])
    shown = {name: (stats.world_means(a[name]), stats.world_means(b[name])) for name in dict.fromkeys((metric, *selection.metrics)) if name in a}
    return {
        "worlds": len(evaluations),
        "repeats": repeats,
        "episodes": 2 * len(evaluations) * repeats,
        "metrics": {name: stats.paired_difference(a[name], b[name]) for name in a},
        "failure": {"event": selection.describe(), **stats.paired_failures(fail_a, fail_b)},
        "cvar": {"metric": metric, **stats.paired_cvar(a[metric], b[metric], alpha, seed=seed)},
        "regressed_worlds": regressed_rows(evaluations, fail_a, fail_b, features, latents, shown, limit),
    }


def search_summary(evaluations: list[Evaluation], spec: EnvSpec, selection: Any, metric: str, maximize: bool, *, limit: int = 20) -> dict:
    """What a differential search found: its most extreme world, the regressed worlds among those it evaluated.

    Returns:
        {"evaluations", "episodes", "metric", "maximize", "best": the extreme world (where, score B − A,
        A's and B's means), "largest_drop" (A − B; B − A when maximising), "regressed" (count),
        "first_regressed" (1-based evaluation at which one was first found, or None), "regressed_worlds"}.
    """
    fail_a, fail_b, a, b = failure_masks(evaluations, spec, selection)
    scores = np.array([e.score for e in evaluations], np.float64)
    best = int(np.nanargmax(scores) if maximize else np.nanargmin(scores))
    regressed = np.flatnonzero(fail_b & ~fail_a)
    features, latents = features_of(evaluations, spec)
    shown = {name: (stats.world_means(a[name]), stats.world_means(b[name])) for name in dict.fromkeys((metric, *selection.metrics)) if name in a}
    return {
        "evaluations": len(evaluations),
        "episodes": 2 * len(evaluations) * int(next(iter(a.values())).shape[1]),
        "metric": metric,
        "maximize": maximize,
        "best": {
            **world_ref(evaluations[best]),
            "score": float(scores[best]),
            "a": float(shown[metric][0][best]),
            "b": float(shown[metric][1][best]),
        },
        "largest_drop": float(scores[best] if maximize else -scores[best]),
        "regressed": int(len(regressed)),
        "first_regressed": int(regressed[0]) + 1 if len(regressed) else None,
        "regressed_worlds": regressed_rows(evaluations, fail_a, fail_b, features, latents, shown, limit),
    }
