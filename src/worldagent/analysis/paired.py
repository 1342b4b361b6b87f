"""Paired evaluations read back: the statistics of ``analysis.diff`` over a diff campaign's evaluations.

A paired evaluation (``differential.PairedObjective``) holds, per episode, B's metrics under their
names and A's under ``A.<name>`` (``BASELINE``). ``summarise`` gives what ``worldagent diff``
reports about a world set; ``search_summary`` what a differential search found. Both read only
evaluations (and the store, for the worlds themselves), never an agent. Counts of regressed worlds
count distinct repaired worlds (``store.world_digest``) where a count is of worlds, not of samples.

Confirmation (``pair_row``, ``confirmed_pairs``): a regressed world is a selection (B failed and A
passed on a few episodes), so it is replayed for both agents on the same fresh episodes
(``analysis.confirm``; its keys depend on the world and the seed only, so A and B share them: common
random numbers, by design). "Regressed" as a confirmed claim needs B's confirmed failure (every
clause's confirmed interval beyond its threshold) *and* A's confirmed pass (some clause's confirmed
interval wholly on the passing side): the claim is a change of verdict, so each verdict is confirmed.
A confirmed B − A failure-rate difference above 0 would also count worlds where both fail (A 0.9,
B 1.0), a different claim; it is reported beside each row (paired over the shared episodes).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from worldagent.analysis import diff as stats
from worldagent.envs.registry import EnvSpec
from worldagent.errors import WorldagentError
from worldagent.store import Evaluation, RunStore, world_digest

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
        "failure": ``paired_failures`` with "event" and "regressed_distinct" (distinct repaired worlds; None without
        the store), "cvar": ``paired_cvar`` with "metric",
        "regressed_worlds": rows (``regressed_rows``)}.
    """
    fail_a, fail_b, a, b = failure_masks(evaluations, spec, selection)
    features, latents = features_of(evaluations, spec, store)
    repeats = int(next(iter(a.values())).shape[1])
    shown = {name: (stats.world_means(a[name]), stats.world_means(b[name])) for name in dict.fromkeys((metric, *selection.metrics)) if name in a}
    regressed = [evaluations[i] for i in np.flatnonzero(fail_b & ~fail_a)]
    distinct = len(set(world_digests(regressed, store))) if store is not None or all(e.world is not None for e in regressed) else None
    return {
        "worlds": len(evaluations),
        "repeats": repeats,
        "episodes": 2 * len(evaluations) * repeats,
        "metrics": {name: stats.paired_difference(a[name], b[name]) for name in a},
        # "regressed" counts sampled worlds (the paired statistics' unit); "regressed_distinct" the repaired worlds among them
        "failure": {"event": selection.describe(), **stats.paired_failures(fail_a, fail_b), "regressed_distinct": distinct},
        "cvar": {"metric": metric, **stats.paired_cvar(a[metric], b[metric], alpha, seed=seed)},
        "regressed_worlds": regressed_rows(evaluations, fail_a, fail_b, features, latents, shown, limit),
    }


def world_digests(evaluations: Sequence[Evaluation], store: RunStore | None = None) -> list[str]:
    """Each evaluation's repaired world's digest: its world as loaded, else read from ``store``."""
    found = []
    for e in evaluations:
        if e.world is None and store is None:
            raise WorldagentError("counting distinct worlds needs their store; pass the store.")
        found.append(world_digest(e.world if e.world is not None else store.world(e.campaign, e.generation, e.slot)))
    return found


def regressed_order(evaluations, fail_a, fail_b, features, latents) -> list[int]:
    """Indices of the regressed worlds in ``analysis.diff.regressed_ranking``'s order (likeliest first)."""
    return [row["world"] for row in stats.regressed_ranking(fail_a, fail_b, features, latents)]


def distinct_firsts(indices: Sequence[int], digests: Sequence[str]) -> list[int]:
    """The first of ``indices`` for each distinct world (``digests``, aligned with ``indices``), in order."""
    seen: dict[str, int] = {}
    for i, digest in zip(indices, digests):
        seen.setdefault(digest, int(i))
    return list(seen.values())


def search_summary(
    evaluations: list[Evaluation], spec: EnvSpec, selection: Any, metric: str, maximize: bool, *, store: RunStore | None = None, limit: int = 20
) -> dict:
    """What a differential search found: its most extreme world, the regressed worlds among those it evaluated.

    Returns:
        {"evaluations", "episodes", "metric", "maximize", "best": the extreme world (where, score B − A,
        A's and B's means), "largest_drop" (A − B; B − A when maximising), "regressed" (distinct regressed
        worlds), "regressed_evaluations" (evaluations of them: a search re-evaluates a world it likes),
        "first_regressed" (1-based evaluation at which one was first found, or None), "regressed_worlds"
        (one row per distinct world)}.
    """
    fail_a, fail_b, a, b = failure_masks(evaluations, spec, selection)
    scores = np.array([e.score for e in evaluations], np.float64)
    best = int(np.nanargmax(scores) if maximize else np.nanargmin(scores))
    regressed = np.flatnonzero(fail_b & ~fail_a)
    digests = dict(zip(regressed.tolist(), world_digests([evaluations[i] for i in regressed], store)))
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
        "regressed": len(set(digests.values())),
        "regressed_evaluations": int(len(regressed)),
        "first_regressed": int(regressed[0]) + 1 if len(regressed) else None,
        # a world evaluated again is listed once: its later evaluations are left out of the regressed (not of the passing)
        "regressed_worlds": regressed_rows(evaluations, fail_a | ~distinct_mask(len(evaluations), digests), fail_b, features, latents, shown, limit),
    }


def distinct_mask(count: int, digests: dict[int, str]) -> np.ndarray:
    """bool[count]: True except at the later evaluations of a world already seen among ``digests`` {index: digest}."""
    keep = np.ones(count, bool)
    seen: set[str] = set()
    for i in sorted(digests):
        keep[i] = digests[i] not in seen
        seen.add(digests[i])
    return keep


# -- confirmation: both agents on the same fresh episodes --------------------------------------------


def side_of(evaluation: Evaluation, side: str) -> Evaluation:
    """``evaluation`` with one agent's episodes only (side "a": A's, ``A.<name>`` renamed ``<name>``; "b": B's), so
    that a confirmation's found figures are that agent's."""
    if side == "a":
        episodes = [{k[len(BASELINE) :]: v for k, v in e.items() if k.startswith(BASELINE)} for e in evaluation.episodes]
    else:
        episodes = [{k: v for k, v in e.items() if not k.startswith(BASELINE)} for e in evaluation.episodes]
    return dataclasses.replace(evaluation, episodes=episodes)


def refuted(clause: Any, values: np.ndarray) -> bool:
    """``clause`` fails beyond doubt on fresh episodes ``values`` f64[E]: the whole interval on its passing side."""
    from worldagent.analysis.confirm import clause_confirmed

    negation = {">": "<=", ">=": "<", "<": ">=", "<=": ">", "==": "!=", "!=": "=="}[clause.op]
    return clause_confirmed(dataclasses.replace(clause, op=negation), values)


def confirmed_passing(confirmed: Any, selection: Any) -> bool:
    """A ``ConfirmedWorld`` passes beyond doubt: some clause of the failure is refuted by its fresh episodes."""
    from worldagent.analysis.confirm import metric_values

    return any(refuted(clause, metric_values(confirmed.episodes, clause.metric or clause.name)) for clause in selection.clauses)


def paired_interval(a: Any, b: Any, values: Any) -> dict:
    """B − A over the two confirmations' shared episodes (the same keys, in order), with its 95% interval;
    ``values(confirmed) -> f64[E]`` per episode."""
    from worldagent.analysis.confirm import mean_interval

    return mean_interval(values(b) - values(a)).as_dict()


def pair_row(a: Any, b: Any, selection: Any, metrics: Sequence[str]) -> dict:
    """One world confirmed for both agents (``ConfirmedWorld`` s of A and B on the same keys): each one's found
    beside confirmed, the paired B − A differences, and the verdict (``confirmed_regressed``, see the module docstring)."""
    from worldagent.analysis.confirm import event_values, metric_values

    if (a.digest, a.seed) != (b.digest, b.seed):
        raise WorldagentError("A and B were confirmed on different worlds or keys; confirm both on the same picks and seed.")
    row = {**world_ref(b.selected), "world": b.digest, "confirmation_seed": b.seed}
    row |= {"a": a.as_dict(metrics, selection), "b": b.as_dict(metrics, selection)}
    for side, confirmed in (("a", a), ("b", b)):
        row[side]["confirmed_passing"] = confirmed_passing(confirmed, selection)
        for key in ("world", "campaign", "generation", "slot", "confirmation_seed"):
            row[side].pop(key, None)
    row["difference"] = {m: paired_interval(a, b, lambda c, m=m: metric_values(c.episodes, m)) for m in metrics}
    row["failure_rate_difference"] = paired_interval(a, b, lambda c: event_values(c.episodes, selection))
    row["found_regressed"] = bool(selection.mask([b.selected])[0] and not selection.mask([a.selected])[0])
    row["confirmed_regressed"] = bool(row["b"]["confirmed_failing"] and row["a"]["confirmed_passing"])
    return row


def confirmed_pairs(rows: Sequence[dict], found_regressed: int, repeats: int, selection: Any) -> dict:
    """Counts over ``pair_row`` s of distinct worlds: how many regressed worlds were found (distinct), how many
    were confirmed for both agents, and how many the confirmation calls regressed."""
    return {
        "event": selection.describe(),
        "repeats": int(repeats),
        "found_regressed": int(found_regressed),
        "checked": len(rows),
        "regressed": int(sum(row["confirmed_regressed"] for row in rows)),
        "b_confirmed_failing": int(sum(row["b"]["confirmed_failing"] for row in rows)),
        "a_confirmed_passing": int(sum(row["a"]["confirmed_passing"] for row in rows)),
        "episodes": 2 * len(rows) * int(repeats),
        "worlds": list(rows),
    }
