"""Confirmation: every world a search selects, replayed on fresh episodes (DESIGN.md "Noise: the world's share
and confirmation").

A search scores many worlds on a few episodes each and keeps the worst: the world it reports is partly
bad luck (the winner's curse), and the score it was found on is biased the way of the selection. Each
selected world is therefore played again on episodes from a **confirmation key stream** that no search
draws from, and reported as *found* (the selection's figure, labelled so) beside *confirmed* (the fresh
episodes' mean with its 95% interval). Claims about a world rest on the confirmed figure.

The stream (one rule, here): for the run's ``seed`` and a world's digest (``store.world_digest``, the
repaired world's content),

    seed_w = SeedSequence([CONFIRM_TAG, seed, *the digest's first four 32-bit words]).generate_state(1)[0]
    keys   = split(fold_in(key(seed_w), CONFIRM_TAG), repeats)

Searches play ``split(key(s), repeats)`` and never fold a key in, so the two streams share no root;
the tests check a run's confirmation keys against every key its searches drew. The keys depend on the
world, not on who selected it: a world confirmed by two selections (or for two agents, as ``diff``
does) plays the same episodes, and the store keeps one confirmation per (agent, env, world, seed,
repeats), committed world by world, so a killed confirmation resumes where it stopped and every
backend gives the same rows.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np
from scipy import stats

from worldagent.errors import WorldagentError
from worldagent.evaluation.backends import LocalBackend, split
from worldagent.identity import agent_identity
from worldagent.progress import progress_bar
from worldagent.store import Confirmation, Evaluation, RunStore, Selected, world_digest

CONFIRM_TAG = 0x434F4E46  # "CONF"
REPEATS = 64  # fresh episodes for each of the few worlds a search reports
ELITE_REPEATS = 32  # for each elite of an atlas (many more worlds)
BATCH = 8  # worlds confirmed (and committed) at a time
CONFIDENCE = 0.95


def confirmation_seed(seed: int, digest: str) -> int:
    """The confirmation seed of the world with ``digest`` in a run of ``seed`` (see the module docstring)."""
    words = [int(digest[i : i + 8], 16) for i in range(0, 32, 8)]
    return int(np.random.SeedSequence([CONFIRM_TAG, int(seed), *words]).generate_state(1)[0])


def confirmation_keys(seed: int, repeats: int) -> jax.Array:
    """The ``[repeats]`` confirmation episode keys of ``confirmation_seed`` ``seed``."""
    return jax.random.split(jax.random.fold_in(jax.random.key(int(seed)), CONFIRM_TAG), int(repeats))


def agent_key(setup: Any) -> str:
    """What a confirmation's agent is: its identity by content (``identity.agent_identity``), its name (greedy or
    not) and the env options it plays with."""
    from worldagent.agents.policy import agent_record

    identity = agent_identity(agent_record(setup.policy))
    return json.dumps(
        {"agent": identity, "name": str(getattr(setup.policy, "name", "")), "options": dict(setup.options)}, sort_keys=True, default=str
    )


# -- statistics ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Interval:
    """A mean over ``n`` episodes and its 95% interval (Clopper–Pearson for 0/1 values, else Student's t)."""

    mean: float
    low: float
    high: float
    n: int

    def text(self, digits: int = 4) -> str:
        return f"{self.mean:.{digits}g} [{self.low:.{digits}g}, {self.high:.{digits}g}]"

    def as_dict(self) -> dict:
        return {"mean": self.mean, "low": self.low, "high": self.high, "episodes": self.n}


def mean_interval(values: Sequence[float], confidence: float = CONFIDENCE) -> Interval:
    """The mean of ``values`` (non-finite ones left out) and its interval; binary values get the exact binomial one."""
    values = np.asarray(values, np.float64).ravel()
    values = values[np.isfinite(values)]
    n = len(values)
    if n == 0:
        return Interval(float("nan"), float("nan"), float("nan"), 0)
    mean = float(values.mean())
    tail = (1 - confidence) / 2
    if np.isin(values, (0.0, 1.0)).all():
        k = int(values.sum())
        low = 0.0 if k == 0 else float(stats.beta.ppf(tail, k, n - k + 1))
        high = 1.0 if k == n else float(stats.beta.ppf(1 - tail, k + 1, n - k))
        return Interval(mean, low, high, n)
    if n < 2 or values.std() == 0:
        return Interval(mean, mean, mean, n)
    half = float(stats.t.ppf(1 - tail, n - 1) * values.std(ddof=1) / np.sqrt(n))
    return Interval(mean, mean - half, mean + half, n)


def metric_values(episodes: Sequence[dict], metric: str) -> np.ndarray:
    """f64[E]: ``metric`` of each episode (its mean over agents for per-agent metrics; NaN where missing)."""
    return np.array([np.nan if e.get(metric) is None else float(np.mean(e[metric])) for e in episodes], np.float64)


def event_values(episodes: Sequence[dict], selection: Any) -> np.ndarray:
    """f64[E]: 1 where a single episode satisfies every clause of ``selection``, else 0."""
    holds = [clause.holds(metric_values(episodes, clause.metric)) for clause in selection.clauses]
    return np.logical_and.reduce(holds).astype(np.float64) if holds else np.zeros(len(episodes))


def clause_confirmed(clause: Any, values: np.ndarray) -> bool:
    """``clause`` holds beyond doubt on fresh episodes ``values``: the whole 95% interval of their mean on its
    side of the threshold (``==``: every episode at the value; ``!=``: the value outside the interval)."""
    values = np.asarray(values, np.float64)
    interval = mean_interval(values)
    if interval.n == 0 or not np.isfinite(interval.mean):
        return False
    number = clause.number
    if clause.op == "==":
        return bool(clause.holds(values[np.isfinite(values)]).all())
    return {
        ">": interval.low > number,
        ">=": interval.low >= number,
        "<": interval.high < number,
        "<=": interval.high <= number,
        "!=": not (interval.low <= number <= interval.high),
    }[clause.op]


# -- confirmed worlds ----------------------------------------------------------------------------


@dataclass(frozen=True)
class ConfirmedWorld:
    """A selected world (``selected``: the evaluation a search picked) and its confirmation's ``episodes``."""

    selected: Evaluation
    digest: str
    episodes: list[dict]
    seed: int

    @property
    def repeats(self) -> int:
        return len(self.episodes)

    def found(self, metric: str) -> Interval:
        """The selection's figure: ``metric`` over the episodes the world was picked on (biased by the pick)."""
        return mean_interval(metric_values(self.selected.episodes, metric))

    def confirmed(self, metric: str) -> Interval:
        """``metric`` over the fresh episodes, with its 95% interval."""
        return mean_interval(metric_values(self.episodes, metric))

    def failure_rate(self, selection: Any, confirmed: bool = True) -> Interval:
        """The share of (fresh, or found) episodes on which ``selection`` holds, with its exact interval."""
        return mean_interval(event_values(self.episodes if confirmed else self.selected.episodes, selection))

    def holds(self, selection: Any) -> bool:
        """The world is confirmed to have the property: every clause's confirmed interval beyond its threshold."""
        return all(clause_confirmed(clause, metric_values(self.episodes, clause.metric)) for clause in selection.clauses)

    def worse_than(self, selection: Any, baseline: float) -> bool:
        """Its fresh episodes fail more often than ``baseline`` (the agent's rate on random worlds), beyond doubt."""
        return bool(np.isfinite(baseline) and self.failure_rate(selection).low > baseline)

    def as_dict(self, metrics: Sequence[str], selection: Any = None, baseline: float | None = None) -> dict:
        """Found beside confirmed for ``metrics`` (and the event's verdicts), for JSON."""
        e = self.selected
        row: dict = {
            "world": self.digest,
            "campaign": e.campaign,
            "generation": e.generation,
            "slot": e.slot,
            "found": {m: self.found(m).as_dict() for m in metrics},
            "confirmed": {m: self.confirmed(m).as_dict() for m in metrics},
            "confirmation_seed": self.seed,
        }
        if selection is not None:
            row["event"] = selection.describe()
            row["found_failure_rate"] = self.failure_rate(selection, confirmed=False).as_dict()
            row["confirmed_failure_rate"] = self.failure_rate(selection).as_dict()
            row["confirmed_failing"] = self.holds(selection)
            if baseline is not None:
                row["worse_than_random"] = self.worse_than(selection, baseline)
        return row

    def line(self, metric: str) -> str:
        """ "found -281.7 (the selection's, 8 episodes); confirmed -184.6 [-224.7, -144.6] (64 fresh episodes)"."""
        found, confirmed = self.found(metric), self.confirmed(metric)
        return f"found {found.mean:.4g} (the selection's, {found.n} episodes); confirmed {confirmed.text()} ({confirmed.n} fresh episodes)"


def arrays_of(store: RunStore, setup: Any, evaluation: Evaluation) -> dict[str, np.ndarray]:
    """The repaired world of a stored evaluation: as stored, else G(latent) (evaluations stored without worlds)."""
    if evaluation.world is not None:
        return evaluation.world
    try:
        return store.world(evaluation.campaign, evaluation.generation, evaluation.slot)
    except WorldagentError:
        if setup.generator is None or evaluation.latent.size == 0:
            raise
    from worldagent.search.objectives import generate

    world = generate(setup.generator, evaluation.latent[None])
    return setup.spec.world_to_arrays(jax.tree_util.tree_map(lambda leaf: np.asarray(leaf[0]), world))


def confirm(
    store: RunStore,
    setup: Any,
    picks: Sequence[Evaluation],
    *,
    name: str,
    repeats: int = REPEATS,
    seed: int = 0,
    progress: bool = True,
) -> list[ConfirmedWorld]:
    """Replay each picked world on ``repeats`` fresh episodes (confirmation keys), storing each as it finishes.

    Worlds already confirmed for this agent (same world, seed and repeats) are read back, not replayed; a
    world picked twice is played once. ``name`` (e.g. ``strategic:cmaes-min-return-s0``) is recorded with
    each pick and its found score (``store.selections``).

    Args:
        store: the run store; ``setup``: ``experiments.Setup`` (env, agents, options, backend).
        picks: the selected evaluations (their worlds are read from the store, or decoded from their latents).
        name: the selection's name, for provenance.
        repeats: fresh episodes per world (0: none; returns []).
        seed: the run's seed (``confirmation_seed``).

    Returns:
        One ``ConfirmedWorld`` per pick, in order.
    """
    if repeats < 0:
        raise WorldagentError(f"--confirm {repeats}; pass a number of fresh episodes per world (64 by default), or 0 to skip.")
    if repeats == 0 or not picks:
        return []
    from worldagent.search.given import GivenWorlds
    from worldagent.search.objectives import Objective

    spec, agent = setup.spec, agent_key(setup)
    arrays = [arrays_of(store, setup, e) for e in picks]
    digests = [world_digest(a) for a in arrays]
    for e, digest in zip(picks, digests):
        store.add_selection(Selected(name, digest, e.campaign, e.generation, e.slot, _metric_of(store, e), e.score, len(e.episodes)))
    done = {c.world: c for c in store.confirmations(agent, spec.name) if c.seed == int(seed) and c.repeats == int(repeats)}
    missing = list(dict.fromkeys(d for d in digests if d not in done))
    if missing:
        first = {d: arrays[digests.index(d)] for d in missing}
        worlds = spec.stack_worlds([first[d] for d in missing])
        evaluate = GivenWorlds(
            Objective(spec.name, spec.metrics.main, False), setup.env, setup.policy, worlds, repeats, setup.params, confirmation_keys
        )
        backend = setup.backend or LocalBackend()
        seeds = np.array([confirmation_seed(seed, d) for d in missing])
        slots = list(range(len(missing)))
        batches = [(part, np.asarray(part, np.float64)[:, None], seeds[part]) for part in split(slots, backend.workers, BATCH)]
        with progress_bar(f"confirming {len(missing)} world(s) on {repeats} fresh episodes", total=len(missing), enabled=progress) as advance:
            started = time.time()
            for part, outcomes in backend.run(evaluate, batches):
                for slot, outcome in zip(part, outcomes):
                    row = Confirmation(agent, spec.name, missing[slot], int(seed), int(repeats), outcome.episodes, first[missing[slot]])
                    store.add_confirmation(row, started)
                    done[row.world] = row
                advance(len(part))
                started = time.time()
    return [ConfirmedWorld(e, d, done[d].episodes, confirmation_seed(seed, d)) for e, d in zip(picks, digests)]


def _metric_of(store: RunStore, evaluation: Evaluation) -> str:
    campaign = store.campaign(evaluation.campaign)
    return campaign.objective if campaign else ""


def random_failure_rate(evaluations: Sequence[Evaluation], selection: Any) -> float:
    """The share of episodes on random worlds on which ``selection`` holds: the baseline of "worse than average"."""
    values = np.concatenate([event_values(e.episodes, selection) for e in evaluations]) if evaluations else np.zeros(0)
    return float(values.mean()) if len(values) else float("nan")


def confirmed_summary(confirmed: Sequence[ConfirmedWorld], selection: Any = None, baseline: float | None = None) -> dict:
    """Counts over a selection's confirmed worlds: picks, distinct worlds, episodes spent, and (with the event) how
    many the found figure called failing and how many the confirmation does."""
    distinct = {c.digest: c for c in confirmed}
    summary: dict = {
        "picked": len(confirmed),
        "distinct_worlds": len(distinct),
        "confirmation_episodes": sum(c.repeats for c in distinct.values()),
    }
    if selection is not None:
        worlds = list(distinct.values())
        summary["event"] = selection.describe()
        summary["found_failing"] = int(sum(bool(selection.mask([c.selected])[0]) for c in worlds))
        summary["confirmed_failing"] = int(sum(c.holds(selection) for c in worlds))
        if baseline is not None:
            summary["worse_than_random"] = int(sum(c.worse_than(selection, baseline) for c in worlds))
            summary["random_failure_rate"] = baseline
    return summary
