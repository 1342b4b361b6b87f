"""Failure-probability estimates through the run store: one store campaign per estimate.

The estimator's g-th call of ``evaluate`` (``analysis.failure_rate``) is generation g, its
worlds played with ``evaluation_seed(seed, g, slot)`` as in a campaign. ``StoredEvaluate`` makes
``evaluate`` from an agent's evaluator and a run store: each estimate is one store campaign
(``campaign_name``) whose generations are those calls (for importance sampling, the search's
rounds first). A rerun replays the stored generations (their latents must match) and evaluates
only what is missing, so a killed run loses nothing. One campaign per estimate, rather than one
per search round, keeps the store's campaigns readable and resuming a single lookup.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from worldagent.errors import WorldagentError
from worldagent.evaluation.backends import LocalBackend, split
from worldagent.search.campaign import REPLAY_TOLERANCE
from worldagent.store import Campaign, RunStore

if TYPE_CHECKING:  # failure_rate imports this module
    from worldagent.analysis.failure_rate import Scored


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

    def __call__(self, z: np.ndarray, seeds: np.ndarray) -> Scored:
        generation, self.generation = self.generation, self.generation + 1
        done = dict(self.stored.get(generation, {}))
        if any(slot >= len(z) or not np.allclose(e.latent, z[slot], atol=REPLAY_TOLERANCE, rtol=0) for slot, e in done.items()):
            raise WorldagentError(
                f"campaign {self.campaign.name!r} in {self.store.path} holds other worlds at generation {generation} than this run asks "
                "(other settings or code); use another --out."
            )
        self.advance(len(done))
        missing = [slot for slot in range(len(z)) if slot not in done]
        started = time.time()
        for slots, outcomes in self.backend.run(self.outcomes, [(part, z[part], seeds[part]) for part in split(missing, self.backend.workers)]):
            for slot, outcome in zip(slots, outcomes):
                self.store.add(self.campaign, generation, slot, z[slot], self.score([outcome]).margin[0], outcome.episodes, started, outcome.world)
                done[slot] = outcome
            self.advance(len(slots))
        return self.score([done[slot] for slot in range(len(z))])
