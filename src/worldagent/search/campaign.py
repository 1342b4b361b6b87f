"""Campaigns: objective × optimiser × budget × store (DESIGN.md "Campaign", paper §4.4).

A campaign asks its optimiser for a generation of latents, evaluates them through an
``evaluate`` callable, commits each evaluation to the run store as soon as it finishes, and
tells the optimiser the scores. Resuming replays: a fresh optimiser with the same seed is asked
again, generation by generation; every latent it asks must equal the stored one (else the
store was written by other code or settings, and the campaign stops rather than mix the two);
stored scores are told back and only the missing evaluations are run. Evaluation randomness
comes from (seed, generation, slot), not from a running stream, so a resumed campaign ends with
exactly the evaluations of an uninterrupted one.

Every search stays inside the prior's typical set |z| <= r unless its spec says otherwise (``prior_bound``; issue 48,
``prior.py``): the optimiser is wrapped in ``optimisers.WithinPrior``, here and nowhere else, so CMA-ES, BO, the
atlas's CMA-ME and a differential search all pass through it; the radius (or None) is recorded in the campaign's
config as "prior_bound", and resuming with another is refused. Random search samples the prior and records none.
A campaign stored before bounds existed has no "prior_bound" and is resumed as it was searched, without one.

``evaluate(z[n, dim], seeds int[n]) -> list of Outcome``: one outcome per latent. A backend
(``evaluation.backends``) runs a generation's batches here or on Ray workers. A score that
is NaN (a broken policy, a metric that failed) is stored and reported, and the campaign stops
with an error instead of optimising on it.
"""

from __future__ import annotations

import time
import zlib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from worldagent.errors import WorldagentError
from worldagent.evaluation.backends import LocalBackend, split
from worldagent.progress import progress_bar
from worldagent.search.optimisers import OptimiserConfig, WithinPrior, make_optimiser, samples_prior, within_prior_config
from worldagent.search.prior import TYPICAL, bound_text
from worldagent.search.prior import prior_bound as bound_radius
from worldagent.store import Evaluation, RunStore

REPLAY_TOLERANCE = 1e-9


@dataclass(frozen=True)
class Outcome:
    """The result of evaluating one latent.

    Attributes:
        score: the objective: the metric averaged over the world's episodes (paper: 8).
        episodes: one dict of metrics per episode.
        world: the generated world (stored with the evaluation), or None.
    """

    score: float
    episodes: list[dict]
    world: Any = None


@dataclass(frozen=True)
class CampaignSpec:
    """What a campaign optimises and how.

    Attributes:
        name: the campaign's name in the store.
        env: the registered environment's name (``registry.get(env)``).
        objective: the metric's name (e.g. "return", "crashed", "group_reward").
        maximize: the direction.
        optimiser: "cmaes", "bo" or "random".
        budget: evaluations (rounded up to whole generations).
        seed: seed of the optimiser and of every evaluation.
        dim: latent dimension.
        config: optimiser settings.
        chunk: latents evaluated per call of ``evaluate`` (0: a whole generation, or an even
            share per worker of a Ray backend).
        agent: what the agent is (``policy.agent_record``: kind, path, file hash), kept in the
            campaign's config; a campaign is resumed only with an agent of the same files.
        extra: more settings kept in the config (e.g. an atlas's grid); resuming needs the same.
        prior_bound: where the search may go (``prior.prior_bound``): ``prior.TYPICAL`` (the default: the prior's
            99.9% ball), a radius, or None (beyond the prior: the optimiser's own box only). Recorded as the radius.
    """

    name: str
    env: str
    objective: str
    maximize: bool
    optimiser: str
    budget: int
    seed: int
    dim: int = 10
    config: OptimiserConfig = OptimiserConfig()
    chunk: int = 0
    agent: dict | None = None
    extra: dict | None = None
    prior_bound: float | str | None = TYPICAL

    def validate(self) -> None:
        if self.budget < 1:
            raise WorldagentError(f"budget={self.budget}; evaluate at least one world.")
        if self.chunk < 0:
            raise WorldagentError(f"chunk={self.chunk}; pass 0 (whole generations) or a positive size.")
        bound_radius(self.prior_bound, self.dim)


PRIOR_KEY = "prior_bound"  # the campaign config's record of the radius searched within (None: beyond the prior)


def campaign_radius(spec: CampaignSpec, existing: Any, samples_prior: bool) -> tuple[float | None, dict]:
    """(the radius the campaign's latents are kept within, what its config records of it).

    Random search (``samples_prior``) records nothing and is kept as it is; a stored campaign without a record (from
    before bounds) resumes as it was searched; a stored campaign with another radius is refused in one line.
    """
    if samples_prior:
        return None, {}
    if existing is not None and PRIOR_KEY not in existing.config:
        return None, {}
    radius = bound_radius(spec.prior_bound, spec.dim)
    if existing is not None:
        stored = existing.config[PRIOR_KEY]
        if (stored is None) != (radius is None) or (radius is not None and not np.isclose(stored, radius, rtol=1e-12, atol=0)):
            flag = "none" if stored is None else "typical" if stored == bound_radius(TYPICAL, spec.dim) else f"{stored:.17g}"
            raise WorldagentError(
                f"campaign {spec.name!r} searched {bound_text(stored, spec.dim)}, not {bound_text(radius, spec.dim)}; "
                f"resume it with --prior-bound {flag}, or start another campaign (--name or --out)."
            )
    return radius, {PRIOR_KEY: radius}


def searched_where(campaign: Any) -> str:
    """Where a stored campaign (``store.Campaign``) looked for worlds, in words: "drawn from the prior" (random
    search), "searched within |z| <= 5.44 (…)" or "searched beyond the prior (no bound on |z|)" (also a campaign
    from before bounds)."""
    if samples_prior(campaign.optimiser):
        return "drawn from the prior"
    return "searched " + bound_text(campaign.config.get(PRIOR_KEY), int(campaign.config.get("dim", 0)) or 1)


def best_evaluation(evaluations: Sequence[Evaluation], maximize: bool) -> Evaluation | None:
    """The evaluation with the lowest (or highest) finite score, the earliest on ties; None if none is finite."""
    finite = [e for e in evaluations if np.isfinite(e.score)]
    if not finite:
        return None
    scores = np.array([e.score for e in finite])
    return finite[int(np.argmax(scores) if maximize else np.argmin(scores))]


def evaluation_seed(seed: int, generation: int, slot: int, stream: int = 0) -> int:
    """The seed of one evaluation, a function of its place in the campaign and the campaign's ``stream`` only.

    Each campaign draws from its own stream (``campaign_stream`` of its name, kept in its config), so two
    campaigns that share a seed do not play the same episodes at the same (generation, slot); stream 0 is
    the rule of campaigns stored before streams existed (they resume with it). Confirmation episodes come
    from another derivation altogether (``analysis.confirm.confirmation_keys``)."""
    return int(np.random.SeedSequence([seed, generation, slot, *([stream] if stream else [])]).generate_state(1)[0])


def campaign_stream(name: str) -> int:
    """The episode stream of campaign ``name`` (CRC-32 of the name, never 0)."""
    return zlib.crc32(name.encode()) or 1


def stored_seed(campaign: Any, generation: int, slot: int) -> int:
    """The seed a stored campaign (``store.Campaign``) played evaluation (generation, slot) with."""
    return evaluation_seed(campaign.seed, generation, slot, int(campaign.config.get("stream", 0)))


def check_repeats(name: str, path: Any, evaluations: Iterable[Evaluation], repeats: int | None) -> None:
    """Refuse to resume a campaign whose worlds were played another number of times (its config does not record
    it; each stored world's episodes do): mixing both would score old and new worlds differently."""
    counts = sorted({len(e.episodes) for e in evaluations if e.episodes})
    if repeats is None or not counts or counts == [int(repeats)]:
        return
    had = counts[0] if len(counts) == 1 else " or ".join(map(str, counts))
    raise WorldagentError(
        f"campaign {name!r} in {path} played each world {had} times, not --repeats {repeats}; "
        f"pass --repeats {had} to resume it, or another --out (or --seed) for a new campaign."
    )


def run_campaign(
    store: RunStore,
    spec: CampaignSpec,
    evaluate: Callable[[np.ndarray, np.ndarray], Sequence[Outcome]],
    resume: bool = False,
    progress: bool = True,
    backend: Any = None,
    optimiser: Any = None,
    title: str | None = None,
) -> list[Evaluation]:
    """Run (or resume) a campaign to its budget; returns all its evaluations in order.

    ``backend`` (``evaluation.backends``; default local) runs each generation's batches.
    ``optimiser``: a fresh optimiser built by the caller (e.g. the atlas's ``QDOptimiser``);
    default ``make_optimiser(spec.optimiser, ...)``. ``title``: the progress bar's (default: what it optimises).
    """
    spec.validate()
    backend = backend or LocalBackend()
    prior_sampler = optimiser.samples_prior if optimiser is not None else samples_prior(spec.optimiser)
    radius, bound_record = campaign_radius(spec, store.campaign(spec.name) if resume else None, prior_sampler)  # else: refused as existing
    campaign = store.open_campaign(
        spec.name,
        spec.env,
        spec.objective,
        spec.maximize,
        spec.optimiser,
        spec.budget,
        spec.seed,
        {
            "dim": spec.dim,
            **asdict(spec.config),
            **({"agent": spec.agent} if spec.agent else {}),
            **(spec.extra or {}),
            **bound_record,
            "stream": campaign_stream(spec.name),
        },
        resume,
    )
    stored = {(e.generation, e.slot): e for e in store.evaluations(spec.name)}
    check_repeats(spec.name, store.path, stored.values(), getattr(evaluate, "repeats", None))
    config = within_prior_config(spec.optimiser, spec.config, radius)
    optimiser = WithinPrior(optimiser or make_optimiser(spec.optimiser, spec.dim, spec.maximize, spec.seed, config), radius)
    done, generation = 0, 0
    pick = max if spec.maximize else min
    best = pick([e.score for e in stored.values() if np.isfinite(e.score)], default=float("nan"))
    title = title or f"{spec.optimiser} {'max' if spec.maximize else 'min'}imising {spec.objective}"
    with progress_bar(title, total=spec.budget, enabled=progress) as advance:
        while done < spec.budget:
            z = optimiser.ask(optimiser.batch_size if optimiser.whole_generations else min(optimiser.batch_size, spec.budget - done))
            scores = np.full(len(z), np.nan)
            missing = []
            for slot, latent in enumerate(z):
                previous = stored.get((generation, slot))
                if previous is None:
                    missing.append(slot)
                    continue
                if previous.latent.shape != latent.shape or not np.allclose(previous.latent, latent, atol=REPLAY_TOLERANCE, rtol=0):
                    raise WorldagentError(
                        f"campaign {spec.name!r}: replaying generation {generation} asks another latent than the store holds; "
                        "it was written by other code or settings: start a new campaign (--name)."
                    )
                scores[slot] = previous.score
            advance(len(z) - len(missing))
            seeds = {s: stored_seed(campaign, generation, s) for s in missing}
            batches = [(slots, z[slots], np.asarray([seeds[s] for s in slots])) for slots in split(missing, backend.workers, spec.chunk)]
            started = time.time()
            for slots, outcomes in backend.run(evaluate, batches):  # committed as each batch arrives
                for slot, outcome in zip(slots, outcomes):
                    store.add(campaign, generation, slot, z[slot], outcome.score, outcome.episodes, started, outcome.world)
                    scores[slot] = outcome.score
                    if np.isfinite(outcome.score):
                        best = outcome.score if np.isnan(best) else pick(best, outcome.score)
                advance(len(slots), best=best)
            broken = int(np.sum(~np.isfinite(scores)))
            if broken:
                raise WorldagentError(
                    f"campaign {spec.name!r}: {broken} world(s) of generation {generation} scored NaN or infinite "
                    f"({spec.objective}); they are in the store ({store.path}) for inspection, and the search stopped "
                    "rather than optimise on them. Check the policy and the metric."
                )
            optimiser.tell(z, scores)
            done += len(z)
            generation += 1
    return store.evaluations(spec.name)
