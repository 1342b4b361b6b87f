"""Which evaluated worlds become the influenced training distribution (paper §6.2).

The candidates an agent was evaluated on are filtered by a ``Selection``; repeated worlds are
kept once; a search for more such worlds is pointed in the selection's direction; a few of the
selected worlds are picked to draw (Figure 8, right).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.events import Selection, parse_selection
from worldagent.store import world_digest


def resolved(selection: Selection | str, env) -> Selection:
    """``selection`` (or its text) parsed and resolved for ``env`` (a name or ``EnvSpec``)."""
    name = registry.get(env).name
    return (parse_selection(selection, name) if isinstance(selection, str) else selection).resolve(name)


def select_worlds(store, campaign_names: Sequence[str], selection: Selection | str, env) -> tuple[Any, np.ndarray, dict[str, np.ndarray]]:
    """Every evaluated world of the campaigns that has the property (paper §6.2).

    Args:
        store: a ``RunStore``.
        campaign_names: the campaigns whose worlds to consider.
        selection: a ``Selection`` (or its text).
        env: the env's name or ``EnvSpec``.

    Returns:
        (worlds: batched world pytree [k], latents f64[k, dim], {metric: f64[k] per-world means}).

    Raises:
        WorldagentError: when no world matches, saying how many were tried and the range each
            selected metric took on them (so the threshold can be moved), or when the
            campaigns hold no worlds.
    """
    return stacked(selected_evaluations(store, campaign_names, selection, env), selection, env)


def selected_evaluations(store, campaign_names: Sequence[str], selection: Selection | str, env) -> list:
    """The evaluations (worlds kept) of the campaigns that have the property, each distinct world once
    (its first evaluation); refused as ``select_worlds`` says."""
    selection = resolved(selection, env)
    evaluations = [e for name in campaign_names for e in store.evaluations(name, with_worlds=True)]
    if not evaluations:
        raise WorldagentError(f"campaigns {', '.join(campaign_names)} hold no evaluated worlds in {store.path}; evaluate some candidates first.")
    keep = selection.mask(evaluations)
    if not keep.any():
        ranges = "; ".join(f"{metric} ranged {_range(values)}" for metric, values in selection.world_means(evaluations).items())
        raise WorldagentError(
            f"none of the {len(evaluations)} worlds tried matches '{selection.describe()}' ({ranges}); "
            "loosen the selection or try more worlds (--candidates, --search-budget)."
        )
    kept = [i for i, k in enumerate(keep) if k]
    if any(evaluations[i].world is None for i in kept):
        raise WorldagentError(f"the store {store.path} lacks the worlds of some evaluations; rerun the candidates with worlds kept.")
    return [evaluations[i] for i in first_of_each_world(evaluations, kept)]


def stacked(evaluations: Sequence, selection: Selection | str, env) -> tuple[Any, np.ndarray, dict[str, np.ndarray]]:
    """(worlds [k], latents f64[k, dim], {metric: f64[k]}) of evaluations with worlds: the selection's
    metrics as found (averaged over the episodes each world was evaluated on)."""
    spec = registry.get(env)
    latents = np.stack([e.latent for e in evaluations])
    return spec.stack_worlds([e.world for e in evaluations]), latents, resolved(selection, spec).world_means(evaluations)


def first_of_each_world(evaluations: Sequence, indices: Sequence[int]) -> list[int]:
    """``indices`` without repeated worlds (the first evaluation of each is kept).

    Many latents decode to one world (racing's G maps z to a dataset track) and a search
    revisits the worlds it likes, so the new distribution is uniform over distinct worlds,
    not over visits.
    """
    seen, unique = set(), []
    for i in indices:
        digest = world_digest(evaluations[i].world)
        if digest not in seen:
            seen.add(digest)
            unique.append(i)
    return unique


def _range(values: np.ndarray) -> str:
    finite = values[np.isfinite(values)]
    return f"{finite.min():.4g} to {finite.max():.4g}" if len(finite) else "NaN only"


def search_direction(selection: Selection, means: np.ndarray) -> bool:
    """Whether the search maximises the first clause's metric: up for > and >=, down for < and <=;
    for == toward the number from the candidates' mean ``means`` f[n], for != away from it."""
    clause = selection.clauses[0]
    if clause.op in (">", ">="):
        return True
    if clause.op in ("<", "<="):
        return False
    centre = float(np.nanmean(means)) if np.any(np.isfinite(means)) else clause.number
    toward = centre < clause.number
    return toward if clause.op == "==" else not toward


def search_target(selection: Selection) -> str:
    """What a search pushes toward (part of the "worlds" stage of the plan when there is a search)."""
    clause = selection.clauses[0]
    direction = "max" if clause.op in (">", ">=") else "min" if clause.op in ("<", "<=") else f"{clause.op} {clause.number:g}"
    return f"{clause.metric} {direction}"


def example_indices(values: dict[str, np.ndarray], count: int = 4) -> np.ndarray:
    """Up to ``count`` worlds spread evenly over the first selected metric's range (Figure 8, right)."""
    first = np.asarray(next(iter(values.values())))
    order = np.argsort(first, kind="stable")
    picks = np.unique(np.round(np.linspace(0, len(order) - 1, min(count, len(order)))).astype(int))
    return order[picks]
