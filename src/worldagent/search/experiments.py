"""The paper's evaluation experiments as library calls (paper §6.1, Figures 6 and 7).

- ``random_evaluation``: the metric over worlds z ~ N(0, I) (§6.1.1, Figure 6a), the campaign
  ``worldagent evaluate random`` runs, under the same name, so either reuses the other's.
- ``strategic_evaluation``: the World Agent's strategic evaluation (§6.1.2, Figure 6b): one
  campaign minimising and one maximising the metric; the worst and best worlds found.
- ``compare_optimisers``: the optimisers' sample efficiency (§6.1.3, Figure 7): campaigns of
  each optimiser for several seeds; per seed, the scores in evaluation order.

Every campaign is written to the run store as it goes and is resumed by name, so rerunning an
experiment evaluates nothing new and a killed one loses nothing it finished.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from worldagent.errors import WorldagentError
from worldagent.search.campaign import CampaignSpec, evaluation_seed, run_campaign
from worldagent.search.objectives import LatentObjective, Objective
from worldagent.search.optimisers import OPTIMISERS, OptimiserConfig
from worldagent.store import Evaluation, RunStore

RANDOM_BATCH = 250  # latents per round of a random evaluation (as `worldagent evaluate random`)


def random_campaign_name(metric: str, seed: int) -> str:
    """The name ``worldagent evaluate random`` gives its campaign (shared on purpose)."""
    return f"random-{metric}-s{seed}"


def strategic_campaign_names(optimiser: str, metric: str, seed: int) -> tuple[str, str]:
    """(minimising, maximising) campaign names of a strategic evaluation."""
    return f"{optimiser}-min-{metric}-s{seed}", f"{optimiser}-max-{metric}-s{seed}"


def comparison_campaign_name(optimiser: str, maximize: bool, metric: str, seed: int) -> str:
    """The campaign name of one optimiser and seed in an optimiser comparison."""
    return f"compare-{optimiser}-{'max' if maximize else 'min'}-{metric}-s{seed}"


def _stored_config(store: RunStore, name: str) -> OptimiserConfig | None:
    """The optimiser settings campaign ``name`` was started with (None if it does not exist)."""
    existing = store.campaign(name)
    if existing is None:
        return None
    fields = OptimiserConfig.__dataclass_fields__
    return OptimiserConfig(**{key: value for key, value in existing.config.items() if key in fields})


def _campaign(
    store, name, env_name, env, policy, G, params, metric, maximize, optimiser, budget, seed, repeats, config, progress, resume
) -> list[Evaluation]:
    """Run (or resume) campaign ``name`` of ``metric`` over G's latent space; its evaluations in order.

    ``config`` None: the settings the campaign was started with, else the defaults, so a rerun
    resumes whatever settings started it."""
    if optimiser not in OPTIMISERS:
        raise WorldagentError(f"unknown optimiser {optimiser!r}; use one of: {', '.join(OPTIMISERS)}.")
    if repeats < 1:
        raise WorldagentError(f"repeats={repeats}; play at least one episode per world.")
    objective = LatentObjective(Objective(env_name, metric, maximize), env, policy, G, repeats, params)
    config = config or _stored_config(store, name) or OptimiserConfig()
    spec = CampaignSpec(name, env_name, metric, maximize, optimiser, budget, seed, G.latent_dim, config)
    return run_campaign(store, spec, objective, resume=resume, progress=progress)


def random_evaluation(
    store: RunStore,
    env_name: str,
    env,
    policy,
    G,
    params,
    metric: str,
    *,
    worlds: int = 1000,
    repeats: int = 8,
    seed: int = 0,
    progress: bool = True,
    resume: bool = True,
) -> list[Evaluation]:
    """The metric on ``worlds`` random worlds G(z), z ~ N(0, I) (paper §6.1.1, Figure 6a).

    The campaign is ``random-{metric}-s{seed}``, as ``worldagent evaluate random`` names it. If it
    already holds at least ``worlds`` evaluations, the first ``worlds`` are returned and nothing
    is run; otherwise it is resumed with the settings it was started with.

    Returns:
        ``worlds`` evaluations in order.
    """
    if worlds < 1:
        raise WorldagentError(f"random worlds = {worlds}; evaluate at least one random world.")
    name = random_campaign_name(metric, seed)
    stored = store.evaluations(name)
    if len(stored) >= worlds:
        return stored[:worlds]
    config = _stored_config(store, name) or OptimiserConfig(random_batch=min(worlds, RANDOM_BATCH))
    evaluations = _campaign(store, name, env_name, env, policy, G, params, metric, True, "random", worlds, seed, repeats, config, progress, resume)
    return evaluations[:worlds]


def best(evaluations: Sequence[Evaluation], maximize: bool) -> Evaluation:
    """The evaluation with the lowest (or highest) finite score; the earliest on ties."""
    finite = [e for e in evaluations if np.isfinite(e.score)]
    if not finite:
        raise WorldagentError("no world of the campaign has a finite score; check the policy and the metric.")
    scores = np.array([e.score for e in finite])
    return finite[int(np.argmax(scores) if maximize else np.argmin(scores))]


def strategic_evaluation(
    store: RunStore,
    env_name: str,
    env,
    policy,
    G,
    params,
    metric: str,
    *,
    budget: int,
    repeats: int = 8,
    seed: int = 0,
    optimiser: str = "cmaes",
    progress: bool = True,
    resume: bool = True,
    config: OptimiserConfig | None = None,
) -> dict:
    """Find the worlds that minimise and maximise ``metric`` (paper §6.1.2, Figure 6b).

    Args:
        store: the run store.
        env_name: "racing" or "harvest"; ``env``, ``params`` the environment and its parameters.
        policy: the agents; ``G`` the generator.
        metric: canonical metric name (``objectives.metric_name(env_name, "reward")``).
        budget: evaluated worlds per direction (CMA-ES rounds up to whole generations).
        repeats: episodes per world (the paper: 8).
        seed: seed of both campaigns.
        optimiser: "cmaes" (the paper's), "bo" or "random".
        config: optimiser settings (default ``OptimiserConfig()``: CMA-ES population 21).

    Returns:
        {"min": Evaluation, "max": Evaluation, "campaigns": [name_min, name_max],
        "keys": (keys_min, keys_max)} — the ``[repeats]`` episode keys each world was scored
        with, for ``reports.strategic.strategic_figure`` to draw the scored episodes.
    """
    names = strategic_campaign_names(optimiser, metric, seed)
    found = {}
    for direction, name, maximize in (("min", names[0], False), ("max", names[1], True)):
        evaluations = _campaign(
            store, name, env_name, env, policy, G, params, metric, maximize, optimiser, budget, seed, repeats, config, progress, resume
        )
        found[direction] = best(evaluations, maximize)
    with_worlds = {d: _with_world(store, found[d]) for d in found}
    keys = tuple(scored_keys_of(store, with_worlds[d]) for d in ("min", "max"))
    return {"min": with_worlds["min"], "max": with_worlds["max"], "campaigns": list(names), "keys": keys}


def compare_optimisers(
    store: RunStore,
    env_name: str,
    env,
    policy,
    G,
    params,
    metric: str,
    *,
    maximize: bool = False,
    optimisers: Sequence[str] = ("cmaes", "bo", "random"),
    budget: int,
    seeds: Sequence[int] = (0, 1, 2),
    repeats: int = 8,
    progress: bool = True,
    resume: bool = True,
    config: OptimiserConfig | None = None,
) -> dict[str, list[np.ndarray]]:
    """Run each optimiser for each seed on the same objective (paper §6.1.3, Figure 7).

    Every optimiser gets the same budget; CMA-ES, which evaluates whole generations, may run a
    few more worlds, and only the first ``budget`` count, so that all compare on equal terms.

    Random search draws from its own stream (``optimisers.RANDOM_STREAM``), so its worlds are
    not CMA-ES's first generation for the same seed.

    Returns:
        {optimiser: [f64[budget] scores in evaluation order, one per seed]} for
        ``reports.comparison.sample_efficiency``.
    """
    if not optimisers:
        raise WorldagentError("no optimisers to compare; name at least one of: " + ", ".join(OPTIMISERS) + ".")
    if not seeds:
        raise WorldagentError("no seeds; compare over at least one seed.")
    unknown = [o for o in optimisers if o not in OPTIMISERS]
    if unknown:
        raise WorldagentError(f"unknown optimiser {unknown[0]!r}; use some of: {', '.join(OPTIMISERS)}.")
    runs: dict[str, list[np.ndarray]] = {}
    for optimiser in optimisers:
        runs[optimiser] = []
        for seed in seeds:
            name = comparison_campaign_name(optimiser, maximize, metric, seed)
            evaluations = _campaign(
                store, name, env_name, env, policy, G, params, metric, maximize, optimiser, budget, seed, repeats, config, progress, resume
            )
            runs[optimiser].append(np.array([e.score for e in evaluations[:budget]], np.float64))
    return runs


def scored_keys_of(store: RunStore, evaluation: Evaluation) -> Any:
    """The ``[episodes]`` keys ``evaluation``'s episodes were played with (its campaign's seed)."""
    from worldagent.evaluation.trajectories import scored_keys

    campaign = store.campaign(evaluation.campaign)
    if campaign is None:
        raise WorldagentError(f"campaign {evaluation.campaign!r} is not in {store.path}; pass the store it was run in.")
    return scored_keys(evaluation_seed(campaign.seed, evaluation.generation, evaluation.slot), len(evaluation.episodes))


def _with_world(store: RunStore, evaluation: Evaluation) -> Evaluation:
    """``evaluation`` with its stored world loaded (``evaluations()`` skips worlds by default)."""
    if evaluation.world is not None:
        return evaluation
    for candidate in store.iter_evaluations(evaluation.campaign, with_worlds=True):
        if (candidate.generation, candidate.slot) == (evaluation.generation, evaluation.slot):
            return candidate
    return evaluation
