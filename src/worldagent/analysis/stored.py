"""Failure-probability estimates read back from a run store, with no agent and no generator.

``experiments.failure_rate`` keeps each estimate as one store campaign whose generations are
the estimator's calls of ``evaluate`` (``analysis.failure_rate``). The estimators are
deterministic given their seed and what ``evaluate`` returns, so running them again over the
stored generations gives the same estimate, interval and ESS: the report recomputes its
probability table that way instead of copying a phase's log.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from worldagent.analysis import failure_rate as fr
from worldagent.analysis.surrogate import cached_describer
from worldagent.errors import WorldagentError
from worldagent.evaluation.backends import LocalBackend, split
from worldagent.search.campaign import REPLAY_TOLERANCE, campaign_stream, stored_seed
from worldagent.store import Campaign, RunStore


def campaign_name(method: str, event: str, seed: int) -> str:
    """``failure-is-crash_rate>0.5-s0``: the store campaign of one estimate."""
    return f"failure-{method}-{''.join(event.split())}-s{seed}"


class StoredEvaluate:
    """``evaluate(z, seeds) -> Scored`` that commits every world to a store campaign and replays it on a rerun.

    Args:
        store: the run store; ``campaign``: the estimate's (``RunStore.open_campaign``).
        outcomes: ``(z, seeds) -> [Outcome]`` (``search.objectives.LatentObjective``).
        score: ``[worlds with .episodes] -> Scored`` (``score_worlds`` with the selection).
        backend: runs the batches (``evaluation.backends``; None: here).
        advance: called with the number of worlds done (a progress bar).
    """

    def __init__(
        self, store: RunStore, campaign: Campaign, outcomes: Callable, score: Callable, backend: Any = None, advance: Callable | None = None
    ):
        self.store, self.campaign, self.outcomes, self.score = store, campaign, outcomes, score
        self.backend, self.advance = backend or LocalBackend(), advance or (lambda done: None)
        self.stored: dict[int, dict] = {}
        for evaluation in store.iter_evaluations(campaign.name):
            self.stored.setdefault(evaluation.generation, {})[evaluation.slot] = evaluation
        self.generation = 0

    def __call__(self, z: np.ndarray, seeds: np.ndarray) -> fr.Scored:
        generation, self.generation = self.generation, self.generation + 1
        done = dict(self.stored.get(generation, {}))
        if any(slot >= len(z) or not np.allclose(e.latent, z[slot], atol=REPLAY_TOLERANCE, rtol=0) for slot, e in done.items()):
            raise WorldagentError(
                f"campaign {self.campaign.name!r} in {self.store.path} holds other worlds at generation {generation} than this run asks "
                "(other settings or code); use another --out."
            )
        self.advance(len(done))
        missing = [slot for slot in range(len(z)) if slot not in done]
        seeds = np.array([stored_seed(self.campaign, generation, slot) for slot in range(len(z))], np.int64)  # the campaign's own stream
        started = time.time()
        for slots, outcomes in self.backend.run(self.outcomes, [(part, z[part], seeds[part]) for part in split(missing, self.backend.workers)]):
            for slot, outcome in zip(slots, outcomes):
                self.store.add(self.campaign, generation, slot, z[slot], self.score([outcome]).margin[0], outcome.episodes, started, outcome.world)
                done[slot] = outcome
            self.advance(len(slots))
        return self.score([done[slot] for slot in range(len(z))])


def failure_names(store) -> list[str]:
    """The store's failure-rate campaigns (``failure-mc-…``, ``failure-is-…``), in the order they were made."""
    return [c.name for c in store.campaigns() if c.optimiser in fr.METHODS and "event" in c.config]


def read_estimate(store, name: str) -> fr.Estimate:
    """Estimate campaign ``name`` again from its stored worlds (nothing is evaluated).

    Raises:
        WorldagentError: when ``name`` is no failure-rate campaign, or is unfinished (rerun
            ``worldagent failure-rate`` with the same settings to finish it).
    """
    from worldagent.events import parse_selection

    campaign = store.campaign(name)
    if campaign is None or name not in failure_names(store):
        known = ", ".join(failure_names(store)) or "none"
        raise WorldagentError(f"{name!r} is not a failure-rate campaign of {store.path}; estimates there: {known}.")
    config = campaign.config
    selection = parse_selection(config["event"], campaign.env)
    first = next(store.iter_evaluations(name), None)
    if first is None:
        raise WorldagentError(f"estimate {name!r} has no evaluated world yet; rerun `worldagent failure-rate` to finish it.")

    def unfinished(z, seeds):
        raise WorldagentError(f"estimate {name!r} is unfinished in {store.path}; rerun `worldagent failure-rate` with its settings to finish it.")

    evaluate = StoredEvaluate(store, campaign, unfinished, partial(fr.score_worlds, selection))
    dim = len(first.latent)
    common = dict(seed=campaign.seed, batch=config["batch"], target_width=config.get("target_width"))
    if campaign.optimiser == "is":
        fields = fr.ImportanceConfig.__dataclass_fields__
        importance = fr.ImportanceConfig(**{"proposal": "search", **{k: v for k, v in config.items() if k in fields}})  # older stores: search
        surrogate = importance.proposal in fr.POOLED
        describe = cached_describer(store.path.parent / config["pool_cache"], None) if surrogate and "pool_cache" in config else None
        timing = KeptTiming(timing_file(store.path, name)) if surrogate else None
        return fr.importance_sampling(evaluate, dim, config["worlds"], config=importance, describe=describe, timing=timing, **common)
    return fr.monte_carlo(evaluate, dim, config["worlds"], **common)


HITS_CONFIRMED = 20  # distinct hit worlds of an estimate listed and confirmed (in the order drawn)


def hits_of(store: RunStore, name: str, selection: Any) -> list:
    """The evaluations of estimate campaign ``name`` in the event (its "hits", on their own episodes), in the order drawn."""
    found = store.evaluations(name)
    return [e for e, hit in zip(found, selection.mask(found) if found else []) if hit]


def confirm_hits(
    store: RunStore,
    setup: Any,
    selection: Any,
    name: str,
    *,
    seed: int,
    repeats: int | None = None,
    limit: int = HITS_CONFIRMED,
    progress: bool = True,
) -> dict | None:
    """The first ``limit`` distinct hit worlds of estimate ``name`` replayed on ``repeats`` fresh episodes (``analysis.confirm``;
    stored, resumable, named ``failure-rate:<name>``): how many still fail.

    The estimate itself needs no confirmation: every world drawn counts, in the event or not, so P is unbiased
    over the prior. A hit, though, is a world picked for having failed on a few episodes; listed as a failure,
    it is confirmed. In Monte Carlo's order the first hits are a random sample of them, so the share that
    survives estimates the share among all hits.

    Args:
        repeats: fresh episodes per hit (None: ``analysis.confirm.REPEATS``; 0 skips).

    Returns:
        None when ``repeats`` is 0, else {"campaign", "hits" (evaluations in the event), "distinct_hits", "checked",
        ``confirm.confirmed_summary``'s counts, "worlds": ``ConfirmedWorld.as_dict`` per checked world}.
    """
    from worldagent.analysis.confirm import REPEATS, arrays_of, confirm, confirmed_summary
    from worldagent.store import world_digest

    repeats = REPEATS if repeats is None else int(repeats)
    if repeats == 0:
        return None
    hits = hits_of(store, name, selection)
    digests = [world_digest(arrays_of(store, setup, e)) for e in hits]
    firsts: dict[str, Any] = {}
    for digest, hit in zip(digests, hits):
        firsts.setdefault(digest, hit)  # the first evaluation of each world
    picks = list(firsts.values())[: max(0, int(limit))]
    confirmed = confirm(store, setup, picks, name=f"failure-rate:{name}", repeats=repeats, seed=seed, progress=progress)
    metrics = list(selection.metrics)
    return {
        "campaign": name,
        "hits": len(hits),
        "distinct_hits": len(set(digests)),
        "checked": len(picks),
        **confirmed_summary(confirmed, selection),
        "worlds": [c.as_dict(metrics, selection) for c in confirmed],
    }


def timing_file(store_path: Any, campaign: str) -> Path:
    """Where an importance-sampling campaign keeps the timings its plan used: ``pools/<campaign>.timing.json``."""
    return Path(store_path).parent / "pools" / f"{campaign}.timing.json"


class KeptTiming(dict):
    """The per-world seconds a surrogate's plan used, read from ``path`` and written there once measured: a resumed or
    replayed estimate (whose pilot is read back in no time) makes the same decisions (pool size, fallback)."""

    def __init__(self, path: Path):
        self.path = Path(path)
        super().__init__(json.loads(self.path.read_text()) if self.path.exists() else {})

    def update(self, *args, **kwargs) -> None:
        from worldagent.files import write_text

        super().update(*args, **kwargs)
        write_text(self.path, json.dumps(dict(self), indent=1) + "\n")


def estimate_campaign(store, setup, selection, method: str, *, worlds: int, importance, target_width, seed: int, progress: bool, say=None):
    """One estimate of ``selection`` by ``method`` ("mc" or "is"), as a store campaign that a rerun resumes.

    The surrogate's pool descriptors are kept per generator (its fingerprint) and seed, whatever
    the event (``surrogate.pool_cache``): a second event on the same seed describes nothing new.
    """
    from worldagent.agents.policy import agent_record
    from worldagent.analysis.surrogate import distinct_describer, pool_cache
    from worldagent.progress import progress_bar
    from worldagent.provenance import fingerprint
    from worldagent.search.objectives import LatentObjective, Objective

    searched = fr.learning_worlds(importance)
    total = worlds + (searched if method == "is" else 0)
    config = {"event": selection.text, "repeats": setup.repeats, "batch": fr.BATCH, "agent": agent_record(setup.policy)}
    config |= {"worlds": int(worlds), "target_width": target_width}  # what ``read_estimate`` replays
    surrogate = method == "is" and importance.proposal in fr.POOLED
    if method == "is":
        config |= asdict(importance)
    if surrogate:
        config["pool_cache"] = str(pool_cache(store.path, fingerprint(setup.generator, setup.spec.name), seed).relative_to(store.path.parent))
    name = campaign_name(method, selection.text, seed)
    config["stream"] = campaign_stream(name)
    campaign = store.open_campaign(name, setup.spec.name, "margin", True, method, total, seed, config, True)
    objective = Objective(setup.spec.name, selection.metrics[0], True)
    outcomes = LatentObjective(objective, setup.env, setup.policy, setup.generator, setup.repeats, setup.params, keep_worlds=False)
    with progress_bar(f"{method}: P({selection.describe()})", total=total, enabled=progress) as advance:
        evaluate = StoredEvaluate(store, campaign, outcomes, partial(fr.score_worlds, selection), setup.backend, advance)
        if not surrogate:
            estimator = fr.monte_carlo if method == "mc" else partial(fr.importance_sampling, config=importance)
            return estimator(evaluate, setup.generator.latent_dim, worlds, seed=seed, batch=fr.BATCH, target_width=target_width)
        describe = cached_describer(store.path.parent / config["pool_cache"], distinct_describer(setup.spec, setup.generator, progress=progress))
        timing = KeptTiming(timing_file(store.path, name))
        return fr.importance_sampling(
            evaluate, setup.generator.latent_dim, worlds, config=importance, seed=seed, batch=fr.BATCH, target_width=target_width,
            describe=describe, timing=timing, say=say,
        )  # fmt: skip
