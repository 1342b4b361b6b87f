"""Which evaluated worlds become the influenced training distribution (paper §6.2).

The candidates an agent was evaluated on are filtered by a ``Selection``; repeated worlds are
kept once; a search for more such worlds is pointed in the selection's direction; a few of the
selected worlds are picked to draw (Figure 8, right).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from typing import Any

import numpy as np

from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.events import Selection, parse_selection


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
    spec = registry.get(env)
    selection = resolved(selection, spec)
    evaluations = [e for name in campaign_names for e in store.evaluations(name, with_worlds=True)]
    if not evaluations:
        raise WorldagentError(f"campaigns {', '.join(campaign_names)} hold no evaluated worlds in {store.path}; evaluate some candidates first.")
    means = selection.world_means(evaluations)
    keep = selection.mask(evaluations)
    if not keep.any():
        ranges = "; ".join(f"{metric} ranged {_range(values)}" for metric, values in means.items())
        raise WorldagentError(
            f"none of the {len(evaluations)} worlds tried matches '{selection.describe()}' ({ranges}); "
            "loosen the selection or try more worlds (--candidates, --search-budget)."
        )
    kept = [i for i, k in enumerate(keep) if k]
    if any(evaluations[i].world is None for i in kept):
        raise WorldagentError(f"the store {store.path} lacks the worlds of some evaluations; rerun the candidates with worlds kept.")
    kept = first_of_each_world(evaluations, kept)
    latents = np.stack([evaluations[i].latent for i in kept])
    return spec.stack_worlds([evaluations[i].world for i in kept]), latents, {m: v[kept] for m, v in means.items()}


def first_of_each_world(evaluations: Sequence, indices: Sequence[int]) -> list[int]:
    """``indices`` without repeated worlds (the first evaluation of each is kept).

    Many latents decode to one world (racing's G maps z to a dataset track) and a search
    revisits the worlds it likes, so the new distribution is uniform over distinct worlds,
    not over visits.
    """
    seen, unique = set(), []
    for i in indices:
        world = evaluations[i].world
        digest = hashlib.sha256(b"".join(np.ascontiguousarray(world[name]).tobytes() for name in sorted(world))).digest()
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
