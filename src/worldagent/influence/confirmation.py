"""Influence selects from confirmed worlds (issue 50, item 6): ``influence(..., confirm=N)``, ``--confirm N``.

The candidates are scored on a few episodes each (8), and the worlds whose score has the property
become the influenced training distribution. With a world's share of the outcome as small as
racing's (ICC 0.1), most of that raw selection is luck: a world picked for ``crash_rate > 0.5`` on
8 episodes usually crashes far less on fresh ones. So each selected world is replayed on ``N``
fresh episodes (``analysis.confirm.confirm``: the confirmation key stream, committed world by world
in the influence run's store, so a killed run resumes and a rerun replays nothing) and kept only
if the property holds on its confirmation (``confirmed_property``). The run records how many of
the raw selection survived, and the property's and the env's failure rate on the selected worlds
as found (the selection's episodes) and confirmed (fresh ones), in ``influence.json``'s
``worlds.confirmation``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from worldagent.analysis.confirm import ELITE_REPEATS, ConfirmedWorld, confirm, mean_interval
from worldagent.errors import WorldagentError
from worldagent.events import Selection

DEFAULT_REPEATS = ELITE_REPEATS  # fresh episodes per selected world: a selection can be hundreds of worlds, as an atlas's elites
RULE = "every clause's confirmed 95% interval beyond its threshold (==: every fresh episode at the value)"


def check_confirm(value: Any) -> int:
    """``confirm``: fresh episodes per selected world, 0 (no confirmation: the raw selection) or more."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise WorldagentError(
            f"confirm={value!r}; pass the fresh episodes each selected world is replayed on ({DEFAULT_REPEATS} on the CLI), or 0 to skip (--confirm)."
        )
    return int(value)


def confirmed_property(world: ConfirmedWorld, selection: Selection) -> bool:
    """Whether a selected world keeps its place in the influenced training distribution: the property
    holds on its confirmation (``ConfirmedWorld.holds``: every clause's 95% interval beyond its
    threshold, an ``==`` clause on every fresh episode).

    Why this rule and not "the confirmed mean satisfies the clause": the influenced agents are said
    to train on worlds that have the property, and the experiment asks what training on such worlds
    does; a world kept on its mean alone has the property with odds near even when its true rate is
    near the threshold, and when the world's share of the outcome is small (racing's ICC 0.1) the
    raw selection is crowded with exactly such worlds, so the distribution would again be partly
    luck. The interval rule keeps a world that lacks the property with at most a 2.5% chance (one
    side of a 95% interval), whatever the noise. Its cost is the borderline worlds that do have the
    property, left out: the survivors are fewer and lean to the property's far side, which the
    recorded count (``survived`` of ``selected``) and the confirmed rates show. For an ``==`` clause
    on a non-negative metric (harvest's ``conflict == 0``) both rules are the same: every fresh
    episode has it.
    """
    return world.holds(selection)


def world_rates(worlds: Sequence[ConfirmedWorld], event: Selection, fresh: bool) -> dict:
    """The share of a world's (fresh, or found) episodes on which ``event`` holds, averaged over ``worlds``
    with a 95% interval over worlds (episodes of one world are not independent draws of the selection's rate)."""
    rates = [world.failure_rate(event, confirmed=fresh).mean for world in worlds]
    interval = mean_interval(rates)  # a rate's interval clipped to [0, 1], where a t interval over few worlds may reach past it
    return {
        "mean": interval.mean,
        "low": max(interval.low, 0.0),
        "high": min(interval.high, 1.0),
        "worlds": len(rates),
        "episodes_per_world": worlds[0].repeats if fresh and worlds else None,
    }


def event_rates(confirmed: Sequence[ConfirmedWorld], kept: Sequence[ConfirmedWorld], event: Selection) -> dict:
    """``event``'s rate on the raw selection (found and confirmed) and on the survivors (confirmed)."""
    return {
        "event": event.describe(),
        "selected_found": world_rates(confirmed, event, fresh=False),  # the selection's figure, biased by the pick
        "selected_confirmed": world_rates(confirmed, event, fresh=True),
        "kept_confirmed": world_rates(kept, event, fresh=True),
    }


def confirmation_summary(
    confirmed: Sequence[ConfirmedWorld], kept: Sequence[ConfirmedWorld], selection: Selection, failure: Selection | None, repeats: int, seed: int
) -> dict:
    """What ``influence.json`` records of a confirmed selection: counts, the rule, the rates found and confirmed."""
    summary = {
        "repeats": int(repeats),
        "seed": int(seed),
        "rule": RULE,
        "selected": len(confirmed),
        "survived": len(kept),
        "survived_share": len(kept) / len(confirmed) if confirmed else float("nan"),
        "property": event_rates(confirmed, kept, selection),
        "kept_values": {
            metric: {"found": _mean([w.found(metric).mean for w in kept]), "confirmed": _mean([w.confirmed(metric).mean for w in kept])}
            for metric in selection.metrics
        },
    }
    if failure is not None:
        summary["failure"] = event_rates(confirmed, kept, failure)
    return summary


def _mean(values: Sequence[float]) -> float:
    return float(np.mean(values)) if len(values) else float("nan")


def confirm_selection(
    store, setup: Any, picks: Sequence, selection: Selection, *, repeats: int, seed: int, name: str, failure: Selection | None, progress: bool
) -> tuple[list, dict]:
    """Replay each picked evaluation's world on ``repeats`` fresh episodes and keep those with the property.

    Args:
        store: the influence run's ``RunStore`` (confirmations are committed there, world by world).
        setup: ``experiments.Setup`` of the agent that selected the worlds.
        picks: the raw selection (``worlds.selected_evaluations``: distinct worlds with the property as found).
        selection: the property (resolved); ``failure``: the env's failure event (reported beside it) or None.
        repeats: fresh episodes per world (at least 1); ``seed``: the run's (``confirm.confirmation_seed``).
        name: the selection's name in the store's provenance (``RunStore.selections``).

    Returns:
        (the kept evaluations, in the raw selection's order; ``confirmation_summary``).
    """
    confirmed = confirm(store, setup, picks, name=name, repeats=repeats, seed=seed, progress=progress)
    kept = [world for world in confirmed if confirmed_property(world, selection)]
    return [world.selected for world in kept], confirmation_summary(confirmed, kept, selection, failure, repeats, seed)


class NoneSurvived(WorldagentError):
    """A confirmed selection kept no world: a finding about the agent and the selection, which callers
    that run many steps (``reproduce``) record and go on from; ``summary`` is the confirmation's."""

    def __init__(self, message: str, summary: dict):
        super().__init__(message)
        self.summary = summary


def none_survived(summary: dict, selection: Selection) -> NoneSurvived:
    """The one-line error of a confirmed selection that kept no world."""
    rates = summary["property"]
    return NoneSurvived(
        f"none of the {summary['selected']} worlds with '{selection.describe()}' kept it on {summary['repeats']} fresh episodes "
        f"(per-episode rate found {rates['selected_found']['mean']:.3g}, confirmed {rates['selected_confirmed']['mean']:.3g}); "
        "loosen the selection, try more worlds (--candidates, --search-budget), or pass --confirm 0 for the unconfirmed selection.",
        summary,
    )


def confirmation_line(summary: dict) -> str:
    """One CLI line: how many of the raw selection survived, and the property's rate found beside confirmed."""
    rates = summary["property"]
    found, raw, kept = rates["selected_found"], rates["selected_confirmed"], rates["kept_confirmed"]

    def text(rate: dict) -> str:
        return f"{rate['mean']:.3g} [{rate['low']:.3g}, {rate['high']:.3g}]"

    line = (
        f"confirmed on {summary['repeats']} fresh episodes each: {summary['survived']} of {summary['selected']} selected worlds keep "
        f"{rates['event']} (train on those); its per-episode rate on the selection: found {found['mean']:.3g} (the selection's), "
        f"confirmed {text(raw)}; on the kept worlds {text(kept)}"
    )
    failure = summary.get("failure")
    if failure is not None and failure["event"] != rates["event"]:
        line += f"; failure ({failure['event']}) on the kept worlds: {text(failure['kept_confirmed'])}"
    return line


REPLAY_SEED_OFFSET = 1  # trained agents replay the kept worlds on another confirmation stream than the one that kept them


def trained_on_selected(
    run_dir, setup: Any, result: dict, events: dict[str, Selection], *, repeats: int, greedy: bool = False, progress: bool = True
) -> dict:
    """Every trained agent of an influence run on its influenced training worlds, ``repeats`` fresh episodes each.

    The episodes come from the confirmation key stream of the run's seed + ``REPLAY_SEED_OFFSET``: keys
    that depend on the world only, so the default and influenced agents play the same episodes (paired),
    and not the keys on which the selecting agent's confirmation kept those worlds (a world kept because
    those keys went badly would carry that luck over). Committed to the run's store world by world.

    Args:
        run_dir: the influence directory; ``setup``: the selecting agent's ``experiments.Setup`` (env, options).
        result: its ``influence.json``; ``events``: {name: resolved selection} whose per-episode rates to report.
        repeats: fresh episodes per world and agent.

    Returns:
        {"worlds", "repeats", "seed", "per_seed": {label: {seed: {event or metric: mean over worlds}}},
        "pooled": {event or metric: ``analysis.diff.pooled_difference`` of influenced − default, paired by world}}.
    """
    import dataclasses
    from pathlib import Path

    from worldagent.agents.loaders import load_agent
    from worldagent.analysis.diff import pooled_difference
    from worldagent.influence.cache import load_influenced_worlds
    from worldagent.store import Evaluation, RunStore

    spec, run_dir = setup.spec, Path(run_dir)
    worlds, latents, _ = load_influenced_worlds(run_dir, spec)
    arrays = spec.world_to_arrays(worlds)
    picks = [
        Evaluation("influenced-worlds", 0, i, latents[i], float("nan"), [], 0.0, 0.0, {k: np.asarray(v[i]) for k, v in arrays.items()})
        for i in range(len(latents))
    ]
    seed = int(result["config"]["seed"]) + REPLAY_SEED_OFFSET
    metrics = list(result["metrics"])
    dirs = {name: run_dir / "agents" / name / record["policy"] for name, record in result["agents"].items()}
    values: dict[str, dict[str, dict[str, np.ndarray]]] = {}
    with RunStore(run_dir) as store:
        for name, directory in dirs.items():
            # each loaded as a saved agent (``load_agent``: with its source, the hash of its files): a confirmation is
            # stored under its agent's identity, which a bare ``load_policy`` or ``trained_policies``' shared ``act``
            # would make one for every trained agent (and read the first one's episodes back for all)
            policy = load_agent(spec, str(directory), options=setup.options, greedy=greedy)
            played = confirm(
                store,
                dataclasses.replace(setup, policy=policy),
                picks,
                name=f"influence-replay:{name}",
                repeats=repeats,
                seed=seed,
                progress=progress,
            )
            label, s = name.rsplit("-s", 1)
            rows = {event: np.array([w.failure_rate(selection).mean for w in played]) for event, selection in events.items()}
            rows |= {m: np.array([w.confirmed(m).mean for w in played]) for m in metrics}
            values.setdefault(label, {})[s] = rows
    per_seed = {label: {s: {k: float(np.nanmean(v)) for k, v in rows.items()} for s, rows in by_seed.items()} for label, by_seed in values.items()}
    pooled = {}
    if {"default", "influenced"} <= set(values):
        for key in [*events, *metrics]:
            arm = np.stack([rows[key] for rows in values["influenced"].values()])
            base = np.stack([rows[key] for rows in values["default"].values()])
            row = pooled_difference(arm, base, lambda v: float(np.nanmean(v)))
            pooled[key] = {**row, "apart": bool(row["low"] > 0 or row["high"] < 0)}
    return {
        "worlds": len(picks),
        "repeats": int(repeats),
        "seed": seed,
        "events": {k: v.describe() for k, v in events.items()},
        "per_seed": per_seed,
        "pooled": pooled,
    }
