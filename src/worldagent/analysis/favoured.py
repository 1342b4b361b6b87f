"""The worlds a curriculum favoured, confirmed on fresh episodes (DESIGN.md "Noise: the world's share and confirmation").

An adaptive curriculum (plr, accel, target) scores the latents in its buffer by learning potential or
by a target's margin, and the worlds it scored highest at the end are what the report's Curriculum
section (``reports.curriculum``) and ``worldagent train`` present as where training was steered. Those
scores are noisy, few-episode estimates like any search's, and the highest of many is a selection (the
winner's curse). So the last snapshot's ``FAVOURITES`` highest-scoring latents are decoded by the run's
G(z) and replayed with the trained agent on the confirmation key stream (``analysis.confirm.confirm``).

*Found* is the buffer's own score (the selection's figure: learning potential or margin, over the
episodes the buffer scored the latent on, with agents from along training); *confirmed* is the main
metric and the env's failure event on fresh episodes of the final agent, with 95% intervals.

The favoured latents have no stored evaluation, and none is made for them: a given-worlds campaign on
the search key stream would be a second, unselected estimate, not the figure the curriculum selected
on, and would spend episodes and add a campaign that every reader of the store then sees. Each pick is
an ``Evaluation`` record built from the snapshot (campaign ``SOURCE``, generation the snapshot's
update, slot the buffer slot, score the buffer's, the world G(z)), and its provenance (``Selected``)
records what the score was and over how many episodes; ``confirm`` does the rest (keys, storage,
resume world by world).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import jax
import numpy as np

from worldagent.analysis.confirm import (
    ConfirmedWorld,
    Interval,
    agent_key,
    confirm,
    confirmation_seed,
    event_values,
    mean_interval,
    metric_values,
)
from worldagent.curricula.snapshots import FAVOURITES, favourite_order, load_snapshots
from worldagent.errors import WorldagentError
from worldagent.store import Evaluation, RunStore, Selected, world_digest

SOURCE = "curriculum buffer"  # a favoured pick's "campaign": generation is the snapshot's update, slot its buffer slot


def selection_name(curriculum: str) -> str:
    """The provenance of a curriculum's favoured worlds in the store: ``curriculum:plr-favoured``."""
    return f"curriculum:{curriculum}-favoured"


def scored_by(curriculum: Any) -> str:
    """What the buffer's scores are (the found figure's meaning): learning potential, or a target's margin."""
    target = getattr(curriculum, "target", None)
    return "learning potential" if target is None else f"margin of target {target.text}"


def favoured_picks(snapshot: dict, count: int = FAVOURITES) -> list[Evaluation]:
    """The ``count`` highest-scoring latents of a snapshot as picks (best first; no episodes, no world yet)."""
    update = int(snapshot["update"])
    return [
        Evaluation(SOURCE, update, int(slot), np.asarray(snapshot["z"][slot], np.float32), float(snapshot["score"][slot]), [], 0.0, 0.0)
        for slot in favourite_order(snapshot, count)
    ]


def with_worlds(picks: Sequence[Evaluation], generator: Any, spec: Any) -> list[Evaluation]:
    """``picks`` with their worlds G(z) (repaired, as arrays): decoded as every campaign decodes a latent."""
    from dataclasses import replace

    from worldagent.search.objectives import generate

    if generator is None:
        raise WorldagentError("the favoured worlds are latents of G(z): pass the run's generator (--generator DIR).")
    if not picks:
        return []
    worlds = generate(generator, np.stack([p.latent for p in picks]))
    one = lambda i: jax.tree_util.tree_map(lambda leaf: np.asarray(leaf[i]), worlds)  # noqa: E731
    return [replace(p, world=spec.world_to_arrays(one(i))) for i, p in enumerate(picks)]


def confirm_favoured(
    store: RunStore,
    setup: Any,
    snapshot: dict,
    *,
    curriculum: str,
    score: str,
    repeats: int,
    seed: int = 0,
    count: int = FAVOURITES,
    progress: bool = True,
) -> list[ConfirmedWorld]:
    """Replay a snapshot's ``count`` favoured latents, decoded by ``setup.generator``, on ``repeats`` fresh episodes each.

    Args:
        store: the run store (the confirmations and their provenance are kept there; a rerun reads them back).
        setup: ``experiments.Setup`` of the trained agent and the G(z) the curriculum drew from.
        snapshot: a buffer snapshot (``curricula.snapshots.load_snapshots``), normally the last.
        curriculum: its name (the selection is ``selection_name(curriculum)``).
        score: what the buffer's scores are (``scored_by``), recorded as the found figure's metric.
        repeats: fresh episodes per world (``analysis.confirm.REPEATS`` by default; 0: none, returns []).
        seed: the run's seed (the confirmation stream's).

    Returns:
        One ``ConfirmedWorld`` per favoured latent, best first.
    """
    picks = favoured_picks(snapshot, count)
    name = selection_name(curriculum)
    if repeats <= 0 or not picks:
        return confirm(store, setup, picks, name=name, repeats=repeats, seed=seed, progress=progress)  # [] for 0, its refusal below
    picks = with_worlds(picks, setup.generator, setup.spec)
    for pick in picks:  # recorded before confirm's own record of the pick, which the store then keeps once
        episodes = int(snapshot["count"][pick.slot])
        store.add_selection(Selected(name, world_digest(pick.world), SOURCE, pick.generation, pick.slot, score, pick.score, episodes))
    return confirm(store, setup, picks, name=name, repeats=repeats, seed=seed, progress=progress)


def favoured_record(confirmed: Sequence[ConfirmedWorld], setup: Any, *, curriculum: str, score: str, seed: int) -> dict:
    """What a run keeps of its favoured worlds' confirmation (JSON-able): which stored confirmations they are
    (``stored_favoured`` reads them back) and, per world, found beside confirmed for the main metric."""
    if not confirmed:
        return {}
    metric = setup.spec.metrics.main
    return {
        "selection": selection_name(curriculum),
        "scored_by": score,
        "update": int(confirmed[0].selected.generation),
        "worlds": [c.digest for c in confirmed],
        "confirmation": {"agent": agent_key(setup), "seed": int(seed), "repeats": confirmed[0].repeats},
        "found": [c.selected.score for c in confirmed],
        "confirmed": [c.confirmed(metric).as_dict() for c in confirmed],
        "said": "; " + favoured_line(confirmed, metric, failure_event(setup.spec)),  # the phase's summary: no baseline (no random worlds yet)
    }


def confirm_last_favoured(store: RunStore, setup: Any, run_dir: Any, curriculum: Any, *, repeats: int, seed: int = 0, progress: bool = True) -> dict:
    """Confirm the favoured latents of a training run's last buffer snapshot and return ``favoured_record``
    ({} when the run kept no snapshot, its buffer was empty, or ``repeats`` is 0)."""
    snapshots = load_snapshots(run_dir)
    if not snapshots:
        return {}
    name, score = curriculum.name, scored_by(curriculum)
    found = confirm_favoured(store, setup, snapshots[-1], curriculum=name, score=score, repeats=repeats, seed=seed, progress=progress)
    return favoured_record(found, setup, curriculum=name, score=score, seed=seed)


def stored_favoured(store: RunStore, spec: Any, snapshot: dict, record: dict) -> list[ConfirmedWorld | None]:
    """The favoured worlds' confirmations read back from the store (no episode played), best first: None for a
    world whose row is missing; [] when ``record`` (``favoured_record``) is of another snapshot or empty."""
    if not record or int(record["update"]) != int(snapshot["update"]):
        return []
    picks = favoured_picks(snapshot, len(record["worlds"]))
    where = record["confirmation"]
    seed, repeats = int(where["seed"]), int(where["repeats"])
    rows = {c.world: c for c in store.confirmations(where["agent"], spec.name) if (c.seed, c.repeats) == (seed, repeats)}
    return [
        ConfirmedWorld(pick, digest, rows[digest].episodes, confirmation_seed(seed, digest)) if digest in rows else None
        for pick, digest in zip(picks, record["worlds"])
    ]


def read_favoured(store: RunStore, spec: Any, snapshot: dict, record: dict, randoms: Sequence[Evaluation] | None) -> dict:
    """What the report shows of a run's favoured worlds, read from the store (no episode played).

    Args:
        store: the run store; ``spec``: the env's spec.
        snapshot: the run's last buffer snapshot; ``record``: the agent phase's ``favoured_record``.
        randoms: the evaluations of the run's random campaign (the baseline of "harder than average"), or None.

    Returns:
        {"worlds": ``stored_favoured``, "metric": the main metric, "failure": the env's failure event (None: it has
        none), "baseline": the agent's failure rate on random worlds (None without them), "scored_by": the found
        figure's meaning}.
    """
    from worldagent.analysis.confirm import random_failure_rate

    failure = failure_event(spec)
    baseline = random_failure_rate(randoms, failure) if failure is not None and randoms else None
    worlds = stored_favoured(store, spec, snapshot, record)
    return {"worlds": worlds, "metric": spec.metrics.main, "failure": failure, "baseline": baseline, "scored_by": record.get("scored_by", "")}


def failure_event(spec: Any) -> Any:
    """The env's failure event (``spec.failure``) parsed, None where it declares none."""
    from worldagent.events import parse_selection

    return parse_selection(spec.failure, spec.name) if spec.failure else None


# -- what they say ---------------------------------------------------------------------------------


def distinct(confirmed: Sequence[ConfirmedWorld | None]) -> list[ConfirmedWorld]:
    """The confirmed worlds, each repaired world once (two latents G(z) maps to one world are one world)."""
    return list({c.digest: c for c in confirmed if c is not None}.values())


def pooled_failure(confirmed: Sequence[ConfirmedWorld | None], failure: Any) -> Interval:
    """The failure event's rate over every fresh episode of the distinct favoured worlds, with its exact interval."""
    worlds = distinct(confirmed)
    return mean_interval(np.concatenate([event_values(c.episodes, failure) for c in worlds]) if worlds else [])


def harder_count(confirmed: Sequence[ConfirmedWorld | None], failure: Any, baseline: float) -> tuple[int, int]:
    """(k, N): of N distinct favoured worlds, k whose confirmed failure rate's lower bound lies above ``baseline``."""
    worlds = distinct(confirmed)
    return sum(c.worse_than(failure, baseline) for c in worlds), len(worlds)


def favoured_rows(confirmed: Sequence[ConfirmedWorld], metric: str, failure: Any = None, baseline: float | None = None) -> list[dict]:
    """Found beside confirmed, per favoured world (best first), for JSON: the buffer's score and the episodes it
    scored, the confirmed main metric and failure rate with their intervals, and "worse than random" with a baseline."""
    rows = []
    for rank, c in enumerate(confirmed, start=1):
        row = {
            "rank": rank,
            "update": c.selected.generation,
            "slot": c.selected.slot,
            "world": c.digest,
            "latent": [float(v) for v in c.selected.latent],
            "found_score": c.selected.score,
            "confirmed": {metric: c.confirmed(metric).as_dict()},
            "confirmation_seed": c.seed,
        }
        if failure is not None:
            row["event"] = failure.describe()
            row["confirmed_failure_rate"] = c.failure_rate(failure).as_dict()
            row["confirmed_failing"] = c.holds(failure)
            if baseline is not None:
                row["worse_than_random"] = c.worse_than(failure, baseline)
        rows.append(row)
    return rows


def favoured_line(confirmed: Sequence[ConfirmedWorld | None], metric: str, failure: Any = None, baseline: float | None = None) -> str:
    """One line on what the favoured worlds do on fresh episodes: "k of N favoured worlds confirmed harder than
    average ..." with a baseline (the agent's failure rate on random worlds), else their pooled figures."""
    worlds = distinct(confirmed)
    if not worlds:
        return "the favoured worlds were not confirmed on fresh episodes"
    repeats = worlds[0].repeats
    fresh = f"{repeats} fresh episode{'s' if repeats != 1 else ''} each"
    if failure is None:
        pooled = mean_interval(np.concatenate([metric_values(c.episodes, metric) for c in worlds]))
        return f"{len(worlds)} favoured worlds confirmed on {fresh}: {metric} {pooled.text()} (the env declares no failure event)"
    event = failure.describe()
    if baseline is None or not np.isfinite(baseline):
        pooled = pooled_failure(worlds, failure)
        failing = int(round(pooled.mean * pooled.n))
        return f"{len(worlds)} favoured worlds confirmed on {fresh}: {event} in {failing} of their {pooled.n} episodes, {pooled.text(3)} (no random worlds yet to compare with)"
    k, n = harder_count(worlds, failure, baseline)
    return (
        f"{k} of {n} favoured worlds confirmed harder than average ({event} on {fresh}, its 95% interval above "
        f"the agent's {baseline:.3g} on random worlds)"
    )
