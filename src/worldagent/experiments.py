"""The paper's experiments as library calls: every CLI command and every reproduce phase calls these.

- ``setup(env, agent, generator)``: what every experiment needs, resolved and checked once.
- ``search``: one campaign (``worldagent search``).
- ``random_evaluation``: the metric over worlds z ~ N(0, I) (§6.1.1, Figure 6a).
- ``worlds_evaluation``: the metric over given worlds (a dataset file, explorer exports, a named set).
- ``strategic_evaluation``: one campaign minimising and one maximising the metric; the worst
  and best worlds found (§6.1.2, Figures 1 and 6b).
- ``compare_optimisers``: the optimisers' sample efficiency (§6.1.3, Figure 7).
- ``influence``: retrain on worlds with a property and compare (§6.2, Figure 8).

Every campaign is written to the run store as it goes and is resumed by name (the names come
from the helpers below, the one place they are made), so rerunning an experiment evaluates
nothing new and a killed one loses nothing it finished.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jax
import numpy as np

from worldagent.agents.policy import agent_record
from worldagent.analysis.confirm import REPEATS as CONFIRM_REPEATS
from worldagent.envs import registry
from worldagent.envs.registry import EnvSpec
from worldagent.errors import WorldagentError
from worldagent.search.campaign import CampaignSpec, best_evaluation, evaluation_seed, run_campaign, searched_where, stored_seed
from worldagent.search.objectives import LatentObjective, Objective
from worldagent.search.optimisers import OPTIMISERS, OptimiserConfig
from worldagent.search.prior import TYPICAL
from worldagent.store import Evaluation, RunStore

RANDOM_BATCH = 250  # latents per round of a random evaluation


# -- campaign names (shared by the commands, the reproduce phases and the report) ----------------


def campaign_name(optimiser: str, maximize: bool, metric: str, seed: int) -> str:
    """``cmaes-min-return-s0``: a search's default name, and each half of a strategic evaluation."""
    return f"{optimiser}-{'max' if maximize else 'min'}-{metric}-s{seed}"


def random_campaign_name(metric: str, seed: int) -> str:
    """``random-return-s0``: the random evaluation's campaign."""
    return f"random-{metric}-s{seed}"


def worlds_campaign_name(tag: str, metric: str, seed: int) -> str:
    """``worlds-prefabs-return-s0``: the evaluation of a given world set (``search.given.WorldSet.tag``)."""
    return f"worlds-{tag}-{metric}-s{seed}"


def strategic_campaign_names(optimiser: str, metric: str, seed: int) -> tuple[str, str]:
    """(minimising, maximising) campaign names of a strategic evaluation."""
    return campaign_name(optimiser, False, metric, seed), campaign_name(optimiser, True, metric, seed)


def comparison_campaign_name(optimiser: str, maximize: bool, metric: str, seed: int) -> str:
    """``compare-bo-min-return-s1``: one optimiser and seed of an optimiser comparison."""
    return "compare-" + campaign_name(optimiser, maximize, metric, seed)


def campaign_names(metric: str, seed: int) -> dict[str, str]:
    """{"random", "min", "max"}: the random and (CMA-ES) strategic campaigns of ``metric`` and ``seed``."""
    low, high = strategic_campaign_names("cmaes", metric, seed)
    return {"random": random_campaign_name(metric, seed), "min": low, "max": high}


def comparison_campaign_names(
    metric: str, seeds: Sequence[int], optimisers: Sequence[str] = OPTIMISERS, maximize: bool = False
) -> dict[str, list[str]]:
    """{optimiser: [campaign name per seed]} of an optimiser comparison."""
    return {opt: [comparison_campaign_name(opt, maximize, metric, s) for s in seeds] for opt in optimisers}


# -- the setup -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Setup:
    """What every experiment needs: the env, the agents and the generator, checked against each other.

    Attributes:
        spec: the env's ``EnvSpec``.
        env, params: ``spec.make_env(options)``.
        policy: the agents (a ``Policy``; external ones have ``host = True``).
        generator: G(z) of ``spec``'s worlds (None: given worlds only).
        repeats: episodes per world (the paper: 8).
        options: the env options (checked, defaults filled in).
        backend: where campaigns evaluate their world batches (``evaluation.backends``; None: here).
    """

    spec: EnvSpec
    env: Any
    params: Any
    policy: Any
    generator: Any
    repeats: int = 8
    options: Mapping[str, Any] = field(default_factory=dict)
    backend: Any = None

    def metric(self, name: str) -> str:
        """The canonical metric for ``name`` ("reward": the env's main one); unknown names are refused."""
        return self.spec.metrics.resolve(name, self.spec.name)


def setup(
    env: str | EnvSpec,
    agent: Any,
    generator: Path | str | Any,
    *,
    options: Mapping[str, Any] | None = None,
    greedy: bool = False,
    stochastic: bool = False,
    repeats: int = 8,
    backend: Any = None,
) -> Setup:
    """Resolve an experiment's inputs, failing fast with one line on any mismatch.

    Args:
        env: a registered env's name (or its spec).
        agent: a ``Policy`` or ``HostPolicy``, or text ``agents.loaders.load_agent`` reads: a
            ``worldagent train`` run dir, the policy dir inside it, a scripted policy's name
            (``spec.scripted``), a ``.onnx`` model, a Stable-Baselines3 ``.zip``, or ``module:function``.
        generator: a ``Generator`` or its directory (``worldagent generator train``); None for
            experiments on given worlds only (``worlds_evaluation``).
        options: env options (harvest: ``{"tagger": (0,)}``); those not given are the saved agent's
            own (``policy.json``), then the defaults.
        greedy: trained actor-critics act by argmax instead of sampling.
        stochastic: external agents that return logits sample them instead of taking the argmax.
        repeats: episodes per world (the paper: 8).
        backend: a backend (``evaluation.backends.make_backend``) or None (this process).
    """
    from worldagent.agents.loaders import agent_options

    spec = registry.get(env)
    options = agent_options(spec, agent, options)
    if isinstance(repeats, bool) or not isinstance(repeats, (int, np.integer)) or repeats < 1:
        raise WorldagentError(f"repeats={repeats!r}; play at least one episode per world.")
    env_obj, params = spec.make_env(options)
    if isinstance(generator, (str, Path)):
        from worldagent.worlds.generator import load_generator

        where, generator = generator, load_generator(generator, env=spec.name)[0]
        if generator.env != spec.name:
            raise WorldagentError(f"the generator in {where} makes {generator.env} worlds; pass a {spec.name} generator.")
    elif generator is not None and generator.env != spec.name:
        raise WorldagentError(f"the generator makes {generator.env} worlds; pass a {spec.name} generator.")
    if isinstance(agent, str):
        from worldagent.agents.loaders import load_agent

        agent = load_agent(spec, agent, greedy, options, stochastic)
    return Setup(spec, env_obj, params, agent, generator, int(repeats), options, backend)


# -- campaigns -----------------------------------------------------------------------------------


def _stored_config(store: RunStore, name: str) -> OptimiserConfig | None:
    """The optimiser settings campaign ``name`` was started with (None if it does not exist)."""
    existing = store.campaign(name)
    if existing is None:
        return None
    fields = OptimiserConfig.__dataclass_fields__
    return OptimiserConfig(**{key: value for key, value in existing.config.items() if key in fields})


def search(
    store: RunStore,
    setup: Setup,
    metric: str,
    *,
    maximize: bool,
    optimiser: str,
    budget: int,
    seed: int,
    name: str | None = None,
    resume: bool = False,
    progress: bool = True,
    config: OptimiserConfig | None = None,
    prior_bound: float | str | None = TYPICAL,
) -> tuple[list[Evaluation], CampaignSpec]:
    """Run (or resume) one campaign of ``metric`` over G's latent space (paper §4.4).

    Args:
        store: the run store.
        setup: env, agents, generator (``setup(...)``).
        metric: a metric of the env, an alias, or "reward".
        maximize: the direction.
        optimiser: "cmaes", "bo" or "random".
        budget: evaluated worlds (CMA-ES rounds up to whole generations).
        seed: seed of the optimiser and of every episode.
        name: the campaign's name (default ``campaign_name(optimiser, maximize, metric, seed)``).
        resume: continue a campaign of that name (else an existing one is refused).
        config: optimiser settings; None: those the campaign was started with, else the defaults.
        prior_bound: where the search may go (``CampaignSpec.prior_bound``; default the prior's typical set).

    Returns:
        (its evaluations in order, its ``CampaignSpec``).
    """
    if optimiser not in OPTIMISERS:
        raise WorldagentError(f"unknown optimiser {optimiser!r}; use one of: {', '.join(OPTIMISERS)}.")
    metric = setup.metric(metric)
    name = name or campaign_name(optimiser, maximize, metric, seed)
    objective = LatentObjective(Objective(setup.spec.name, metric, maximize), setup.env, setup.policy, setup.generator, setup.repeats, setup.params)
    config = config or _stored_config(store, name) or OptimiserConfig()
    agent = agent_record(setup.policy)
    spec = CampaignSpec(
        name, setup.spec.name, metric, maximize, optimiser, int(budget), int(seed), setup.generator.latent_dim, config, agent=agent,
        prior_bound=prior_bound,
    )  # fmt: skip
    return run_campaign(store, spec, objective, resume=resume, progress=progress, backend=setup.backend), spec


def random_evaluation(
    store: RunStore, setup: Setup, metric: str = "reward", *, worlds: int = 1000, seed: int = 0, progress: bool = True, resume: bool = True
) -> list[Evaluation]:
    """The metric on ``worlds`` random worlds G(z), z ~ N(0, I) (paper §6.1.1, Figure 6a).

    The campaign is ``random_campaign_name(metric, seed)``. If it already holds at least
    ``worlds`` evaluations, the first ``worlds`` are returned and nothing is run; otherwise it
    is resumed (``resume``) with the settings it was started with.

    Returns:
        ``worlds`` evaluations in order.
    """
    if worlds < 1:
        raise WorldagentError(f"random worlds = {worlds}; evaluate at least one random world.")
    metric = setup.metric(metric)
    name = random_campaign_name(metric, seed)
    stored = store.evaluations(name)
    if len(stored) >= worlds:
        return stored[:worlds]
    config = _stored_config(store, name) or OptimiserConfig(random_batch=min(worlds, RANDOM_BATCH))
    found, _ = search(
        store, setup, metric, maximize=True, optimiser="random", budget=worlds, seed=seed, name=name, resume=resume, progress=progress, config=config
    )
    return found[:worlds]


def worlds_evaluation(store: RunStore, setup: Setup, given: Any, metric: str = "reward", *, seed: int = 0, progress: bool = True) -> list[Evaluation]:
    """The metric on every world of a given set (DESIGN.md "Named world sets"): a dataset file, explorer exports, or
    one of ``spec.world_sets`` (``search.given.world_set``), stored as campaign ``worlds_campaign_name`` and resumed
    by a rerun. With a generator in ``setup``, each world is stored at its encoder mean (the explorer maps it);
    without, with no latent.

    Returns:
        One evaluation per world, in the set's order.
    """
    from worldagent.search.given import GivenWorlds, encoder_latents, run_given

    metric = setup.metric(metric)
    evaluate = GivenWorlds(Objective(setup.spec.name, metric, False), setup.env, setup.policy, given.worlds, setup.repeats, setup.params)
    latents = None if setup.generator is None else encoder_latents(setup.spec, setup.generator, given.worlds)
    name = worlds_campaign_name(given.tag, metric, seed)
    agent = agent_record(setup.policy)
    return run_given(store, name, evaluate, given, seed=seed, agent=agent, latents=latents, backend=setup.backend, progress=progress)


def random_scores(store: RunStore, metric: str, seed: int) -> np.ndarray:
    """f64[worlds]: the stored random evaluation's per-world scores (the baseline of Figures 6b and 7)."""
    return np.array([e.score for e in store.evaluations(random_campaign_name(metric, seed))], np.float64)


def best(evaluations: Sequence[Evaluation], maximize: bool) -> Evaluation:
    """The evaluation with the lowest (or highest) finite score (earliest on ties); refuses none finite."""
    found = best_evaluation(evaluations, maximize)
    if found is None:
        raise WorldagentError("no world of the campaign has a finite score; check the policy and the metric.")
    return found


def strategic_evaluation(
    store: RunStore,
    setup: Setup,
    metric: str = "reward",
    *,
    budget: int,
    seed: int = 0,
    optimiser: str = "cmaes",
    progress: bool = True,
    resume: bool = True,
    config: OptimiserConfig | None = None,
    confirm: int = CONFIRM_REPEATS,
    prior_bound: float | str | None = TYPICAL,
) -> dict:
    """Find the worlds that minimise and maximise ``metric`` (paper §6.1.2, Figure 6b), and confirm them.

    The worst of many noisy scores is partly luck (the winner's curse), so each of the two worlds is
    replayed on ``confirm`` fresh episodes (``analysis.confirm``; selection ``strategic:<campaign>``).

    Args:
        store: the run store; ``setup``: env, agents, generator.
        metric: a metric of the env, an alias, or "reward".
        budget: evaluated worlds per direction (CMA-ES rounds up to whole generations).
        seed: seed of both campaigns (and of the confirmation stream).
        optimiser: "cmaes" (the paper's), "bo" or "random".
        config: optimiser settings (default ``OptimiserConfig()``: CMA-ES population 21).
        confirm: fresh episodes per found world (0: none).
        prior_bound: where both searches may go (``CampaignSpec.prior_bound``; default the prior's typical set).

    Returns:
        {"min": Evaluation, "max": Evaluation (both with their worlds), "campaigns": [name_min,
        name_max], "keys": (keys_min, keys_max), "metric": canonical name, "notes": (note_min,
        note_max), "confirmed": (ConfirmedWorld | None, ConfirmedWorld | None), "confirm": the
        episodes per world, "selections": (name_min, name_max), "searched": where each campaign looked
        (``search.campaign.searched_where``)}: the ``[repeats]`` episode keys each
        world was scored with (to replay the scored episodes) and ``spec.episode_note`` of each ("", or
        e.g. ", 6/8 episodes crashed"); ``confirmed`` is (None, None) when ``confirm`` is 0.
    """
    metric = setup.metric(metric)
    names = strategic_campaign_names(optimiser, metric, seed)
    found = {}
    for direction, name, maximize in (("min", names[0], False), ("max", names[1], True)):
        evaluations, _ = search(
            store,
            setup,
            metric,
            maximize=maximize,
            optimiser=optimiser,
            budget=budget,
            seed=seed,
            name=name,
            resume=resume,
            progress=progress,
            config=config,
            prior_bound=prior_bound,
        )
        found[direction] = with_world(store, best(evaluations, maximize))
    keys = tuple(scored_keys_of(store, found[d]) for d in ("min", "max"))
    notes = tuple(episode_note(setup.spec, found[d]) for d in ("min", "max"))
    selections = tuple(selection_name("strategic", name) for name in names)
    confirmed = tuple(
        confirm_reported(store, setup, found[d], selections[i], repeats=confirm, seed=seed, progress=progress) for i, d in enumerate(("min", "max"))
    )
    return {
        "min": found["min"],
        "max": found["max"],
        "campaigns": list(names),
        "keys": keys,
        "metric": metric,
        "notes": notes,
        "confirmed": confirmed,
        "confirm": int(confirm),
        "selections": selections,
        "searched": tuple(searched_where(store.campaign(name)) for name in names),
    }


def selection_name(command: str, campaign: str) -> str:
    """``strategic:cmaes-min-return-s0``: the provenance name (``store.selections``) of the world ``command`` reports from ``campaign``."""
    return f"{command}:{campaign}"


def confirm_reported(store: RunStore, setup: Setup, evaluation: Evaluation, name: str, *, repeats: int, seed: int, progress: bool = True) -> Any:
    """The ``analysis.confirm.ConfirmedWorld`` of one reported world (``repeats`` fresh episodes), None when ``repeats`` is 0."""
    from worldagent.analysis.confirm import confirm

    confirmed = confirm(store, setup, [evaluation], name=name, repeats=repeats, seed=seed, progress=progress)
    return confirmed[0] if confirmed else None


def episode_note(spec: EnvSpec, evaluation: Evaluation) -> str:
    """``spec.episode_note`` of an evaluation's episodes ("" when the env has none)."""
    return episodes_note(spec, evaluation.episodes)


def episodes_note(spec: EnvSpec, episodes: Sequence[dict]) -> str:
    """``spec.episode_note`` of episodes (a confirmation's or an evaluation's); "" when the env has none."""
    if spec.episode_note is None or not episodes:
        return ""
    shared = set.intersection(*(set(e) for e in episodes))
    return spec.episode_note({n: np.asarray([e[n] for e in episodes]) for n in shared})


def compare_optimisers(
    store: RunStore,
    setup: Setup,
    metric: str = "reward",
    *,
    maximize: bool = False,
    optimisers: Sequence[str] = ("cmaes", "bo", "random"),
    budget: int,
    budgets: Mapping[str, int] | None = None,
    seeds: Sequence[int] = (0, 1, 2),
    progress: bool = True,
    resume: bool = True,
    config: OptimiserConfig | None = None,
    prior_bound: float | str | None = TYPICAL,
) -> dict[str, list[np.ndarray]]:
    """Run each optimiser for each seed on the same objective (paper §6.1.3, Figure 7).

    Every optimiser gets ``budget`` (or its entry in ``budgets``, e.g. ``{"bo": 42}``: BO is
    slow); CMA-ES, which evaluates whole generations, may run a few more worlds, and only the
    first ``budget`` count, so that all compare on equal terms. Random search draws from its own
    stream (``optimisers.RANDOM_STREAM``), so its worlds are not CMA-ES's first generation.
    ``prior_bound``: where every optimiser may go (``CampaignSpec.prior_bound``; default the prior's typical set).

    Returns:
        {optimiser: [f64[budget] scores in evaluation order, one per seed]} for
        ``reports.comparison.sample_efficiency``.
    """
    if not optimisers:
        raise WorldagentError("no optimisers to compare; name at least one of: " + ", ".join(OPTIMISERS) + ".")
    if not seeds:
        raise WorldagentError("no seeds; compare over at least one seed.")
    unknown = [o for o in (*optimisers, *(budgets or {})) if o not in OPTIMISERS]
    if unknown:
        raise WorldagentError(f"unknown optimiser {unknown[0]!r}; use some of: {', '.join(OPTIMISERS)}.")
    metric = setup.metric(metric)
    runs: dict[str, list[np.ndarray]] = {}
    for optimiser in optimisers:
        limit = int((budgets or {}).get(optimiser) or budget)
        runs[optimiser] = []
        for seed in seeds:
            name = comparison_campaign_name(optimiser, maximize, metric, seed)
            evaluations, _ = search(
                store,
                setup,
                metric,
                maximize=maximize,
                optimiser=optimiser,
                budget=limit,
                seed=seed,
                name=name,
                resume=resume,
                progress=progress,
                config=config,
                prior_bound=prior_bound,
            )
            runs[optimiser].append(np.array([e.score for e in evaluations[:limit]], np.float64))
    return runs


def comparison_selection_name(maximize: bool, metric: str) -> str:
    """``compare:min-return``: the provenance name of the worlds an optimiser comparison reports (one per
    optimiser and seed; ``store.selections`` keeps each one's campaign, generation and slot)."""
    return selection_name("compare", f"{'max' if maximize else 'min'}-{metric}")


def comparison_picks(
    store: RunStore,
    metric: str,
    *,
    maximize: bool,
    optimisers: Sequence[str],
    budget: int,
    budgets: Mapping[str, int] | None = None,
    seeds: Sequence[int],
) -> dict[str, list[Evaluation]]:
    """{optimiser: [the world each seed's campaign reports: its best within its budget, with its world]} of a
    stored comparison (``compare_optimisers`` with the same arguments, ``metric`` canonical)."""
    picks: dict[str, list[Evaluation]] = {}
    for optimiser in optimisers:
        limit = int((budgets or {}).get(optimiser) or budget)
        picks[optimiser] = []
        for seed in seeds:
            name = comparison_campaign_name(optimiser, maximize, metric, seed)
            evaluations = store.evaluations(name)[:limit]
            if not evaluations:
                raise WorldagentError(f"campaign {name!r} is not in {store.path}; run compare_optimisers first.")
            picks[optimiser].append(with_world(store, best(evaluations, maximize)))
    return picks


def confirm_optimisers(
    store: RunStore,
    setup: Setup,
    metric: str = "reward",
    *,
    maximize: bool = False,
    optimisers: Sequence[str] = ("cmaes", "bo", "random"),
    budget: int,
    budgets: Mapping[str, int] | None = None,
    seeds: Sequence[int] = (0, 1, 2),
    repeats: int = CONFIRM_REPEATS,
    seed: int = 0,
    progress: bool = True,
) -> dict[str, list[Any]]:
    """Replay the world each optimiser and seed of a comparison reports on ``repeats`` fresh episodes (issue 50).

    Figure 7 ranks optimisers by their best world; a best of many 8-episode scores is partly luck, so the
    ranking is made again on these confirmed values (``reports.comparison.confirmed_efficiency``). All the
    picks are confirmed in one call (selection ``comparison_selection_name``), from the confirmation stream
    of ``seed``: a world two campaigns report plays the same fresh episodes. Stored and read back on a rerun.

    Returns:
        {optimiser: [``analysis.confirm.ConfirmedWorld`` per seed]}, {} when ``repeats`` is 0.
    """
    from worldagent.analysis.confirm import confirm

    metric = setup.metric(metric)
    picks = comparison_picks(store, metric, maximize=maximize, optimisers=optimisers, budget=budget, budgets=budgets, seeds=seeds)
    flat = [pick for optimiser in optimisers for pick in picks[optimiser]]
    confirmed = confirm(store, setup, flat, name=comparison_selection_name(maximize, metric), repeats=repeats, seed=seed, progress=progress)
    if not confirmed:
        return {}
    return {optimiser: confirmed[i * len(seeds) : (i + 1) * len(seeds)] for i, optimiser in enumerate(optimisers)}


def scored_keys_of(store: RunStore, evaluation: Evaluation) -> Any:
    """The ``[episodes]`` keys ``evaluation``'s episodes were played with (its campaign's seed)."""
    from worldagent.evaluation.trajectories import scored_keys

    campaign = store.campaign(evaluation.campaign)
    if campaign is None:
        raise WorldagentError(f"campaign {evaluation.campaign!r} is not in {store.path}; pass the store it was run in.")
    return scored_keys(stored_seed(campaign, evaluation.generation, evaluation.slot), len(evaluation.episodes))


def with_world(store: RunStore, evaluation: Evaluation) -> Evaluation:
    """``evaluation`` with its stored world loaded (``evaluations()`` skips worlds by default)."""
    if evaluation.world is not None:
        return evaluation
    for candidate in store.iter_evaluations(evaluation.campaign, with_worlds=True):
        if (candidate.generation, candidate.slot) == (evaluation.generation, evaluation.slot):
            return candidate
    return evaluation


# -- failure atlas (quality diversity) ----------------------------------------------------------


def atlas_campaign_name(maximize: bool, metric: str, seed: int) -> str:
    """``atlas-min-return-s0``: an atlas's campaign."""
    return f"atlas-{'max' if maximize else 'min'}-{metric}-s{seed}"


def atlas(
    store: RunStore,
    setup: Setup,
    metric: str = "reward",
    *,
    maximize: bool = False,
    budget: int,
    seed: int = 0,
    descriptors: Sequence[str] | None = None,
    cells: int = 10,
    failure: str | None = None,
    name: str | None = None,
    resume: bool = True,
    progress: bool = True,
    confirm: int | None = None,
    prior_bound: float | str | None = TYPICAL,
) -> dict:
    """A failure atlas: the worst (or best) world of every cell of a descriptor grid, by CMA-ME.

    Args:
        store: the run store; ``setup``: env, agents, generator (and backend).
        metric: a metric of the env, an alias, or "reward".
        maximize: look for the highest values (default: the lowest, i.e. failures of a reward).
        budget: evaluated worlds (rounded up to whole generations of 21).
        seed: seed of the emitters, the grid's ranges and every episode.
        descriptors: 1–3 of ``spec.metrics.descriptors`` (default: the spec's defaults).
        cells: cells per descriptor.
        failure: a selection (``"crash_rate > 0.5"``) saying which worlds fail, for the count of
            distinct failing worlds (None: none counted).
        name: the campaign (default ``atlas_campaign_name``); ``resume`` continues it.
        confirm: fresh episodes per elite (default ``analysis.confirm.ELITE_REPEATS``; 0 skips): every
            elite replayed on confirmation keys, giving the corrected archive (``search.corrected_atlas.confirm_elites``).
        prior_bound: where the emitters may go (``CampaignSpec.prior_bound``; default the prior's typical set).

    Returns:
        ``atlas_summary`` of the campaign, with "confirmed": ``search.corrected_atlas.corrected_summary`` (None when skipped).
    """
    from worldagent.analysis.confirm import ELITE_REPEATS
    from worldagent.search.atlas import atlas_optimiser
    from worldagent.search.corrected_atlas import confirm_elites

    metric = setup.metric(metric)
    optimiser, extra = atlas_optimiser(setup.spec, setup.generator, maximize, seed, budget, descriptors, cells)
    selection = failure_selection(failure, setup.spec.name)
    name = name or atlas_campaign_name(maximize, metric, seed)
    dim = setup.generator.latent_dim
    spec = CampaignSpec(
        name, setup.spec.name, metric, maximize, "cma-me", int(budget), int(seed), dim, agent=agent_record(setup.policy), extra=extra,
        prior_bound=prior_bound,
    )  # fmt: skip
    objective = LatentObjective(Objective(setup.spec.name, metric, maximize), setup.env, setup.policy, setup.generator, setup.repeats, setup.params)
    run_campaign(store, spec, objective, resume=resume, progress=progress, backend=setup.backend, optimiser=optimiser)
    found = atlas_summary(store, optimiser.grid, optimiser.describe, [name], maximize, selection)[name]
    repeats = ELITE_REPEATS if confirm is None else int(confirm)
    found["confirmed"] = confirm_elites(store, setup, found, metric, maximize, selection, repeats=repeats, seed=seed, progress=progress)
    return found


def atlas_summary(store: RunStore, grid: Any, describe: Any, campaigns: Sequence[str], maximize: bool, failure: Any = None) -> dict:
    """Each campaign's evaluations on ``grid``: coverage, QD-score and distinct failing worlds.

    Any campaign compares (an atlas, a CMA-ES search, random search): the same grid and the same
    QD-score offset (the worst score over all the campaigns given) for all.

    Returns:
        {campaign: {"evaluations", "archive" (``search.atlas.Archive``), "coverage", "qd_score",
        "failing", "distinct_failing" (None without ``failure``), "qd_offset", "grid", "describe"}}.
    """
    from worldagent.search.atlas import archive_of, distinct_count, qd_offset

    runs = {name: store.evaluations(name) for name in campaigns}
    offset = qd_offset(np.array([e.score for found in runs.values() for e in found]), maximize)
    summary = {}
    for name, found in runs.items():
        scores = np.array([e.score for e in found], np.float64)
        measures = describe(np.stack([e.latent for e in found])) if found else np.zeros((0, len(grid.cells)))
        archive = archive_of(grid, scores, measures, maximize)
        failing = np.flatnonzero(failure.mask(found)) if failure is not None and found else np.zeros(0, int)
        worlds = [w.world for w in store.iter_evaluations(name, with_worlds=True)] if len(failing) else []
        summary[name] = {
            "evaluations": found,
            "archive": archive,
            "coverage": archive.coverage(grid),
            "qd_score": archive.qd_score(offset, maximize),
            "qd_offset": offset,
            "stream": int(store.campaign(name).config.get("stream", 0)) if store.campaign(name) else 0,
            "failing": int(len(failing)) if failure is not None else None,
            "distinct_failing": distinct_count([worlds[i] for i in failing if worlds[i] is not None]) if failure is not None else None,
            "grid": grid,
            "describe": describe,
        }
    return summary


def explain_failures(setup: Setup, summary: dict, failure: Any, *, count: int = 3, seed: int = 0) -> dict:
    """Counterfactual pairs and clusters for an atlas's failing worlds (issue 15, item 3).

    For up to ``count`` failing cells (the lowest first, then far apart), the nearest passing
    world the atlas evaluated gives a segment in latent space; ``analysis.explanations.boundary``
    bisects it for the last failing and first passing world. Boundary latents are evaluated with
    the setup's agent and repeats, each with the episodes its failing world was scored with
    (``seed`` is the atlas's), and are not stored.

    Returns:
        {"pairs": [{"boundary": Boundary, "seed": the episodes' seed, "cell_score": float}],
        "clusters": [analysis.explanations.Cluster] over the failing evaluations,
        "failing": the failing ``Evaluation`` s the clusters index, "failing_measures": their
        descriptors f64[n, k]}.
    """
    from worldagent.analysis.explanations import boundary, clusters, nearest
    from worldagent.search.atlas import distinct_picks

    found, archive = summary["evaluations"], summary["archive"]
    mask = failure.mask(found) if found else np.zeros(0, bool)
    failing = [e for e, bad in zip(found, mask) if bad]
    passing = np.stack([e.latent for e, bad in zip(found, mask) if not bad]) if (~mask).any() else np.zeros((0, setup.generator.latent_dim))
    objective = LatentObjective(
        Objective(setup.spec.name, setup.spec.metrics.main, True), setup.env, setup.policy, setup.generator, setup.repeats, setup.params
    )
    failing_cells = [i for i in range(len(archive.cells)) if mask[archive.best[i]]]
    sub = dataclasses.replace(
        archive,
        scores=archive.scores[failing_cells],
        measures=archive.measures[failing_cells],
        cells=archive.cells[failing_cells],
        best=archive.best[failing_cells],
    )
    pairs = []
    for pick in distinct_picks(sub, False, count) if len(failing_cells) and len(passing) else []:
        worst = found[int(sub.best[pick])]
        # every point of the segment plays the episodes the failing world was scored with, so
        # the verdict changes only where the world does (not with the episodes' randomness)
        episodes_seed = evaluation_seed(seed, worst.generation, worst.slot, summary.get("stream", 0))
        fails = lambda z, s=episodes_seed: failure.mask(objective(z, np.full(len(z), s)))  # noqa: E731
        z_pass = passing[nearest(worst.latent, passing)]
        pairs.append({"boundary": boundary(fails, worst.latent, z_pass), "seed": episodes_seed, "cell_score": float(sub.scores[pick])})
    latents = np.stack([e.latent for e in failing]) if failing else np.zeros((0, setup.generator.latent_dim))
    measures = summary["describe"](latents) if failing else np.zeros((0, len(summary["grid"].cells)))
    return {"pairs": pairs, "clusters": clusters(measures, latents, seed=seed), "failing": failing, "failing_measures": measures}


def failure_selection(text: str | None, env: str) -> Any:
    """The parsed failure event, or None."""
    if text is None:
        return None
    from worldagent.events import parse_selection

    return parse_selection(text, env)


# -- influencing ---------------------------------------------------------------------------------


def influence(
    run_dir: str | Path,
    setup: Setup,
    selection: Any,
    *,
    algo: str | None = None,
    episodes: int | None = None,
    seeds: Sequence[int] = (0, 1, 2),
    candidates: int = 500,
    search_budget: int = 0,
    search: str = "cmaes",
    eval_worlds: int = 200,
    config: Any = None,
    seed: int = 0,
    greedy: bool = False,
    progress: bool = True,
    runs_per_program: int | None = None,
    rounds: int = 1,
    confirm: int = 0,
) -> dict:
    """Train agents on worlds with a property and compare them with default training (paper §6.2, Figure 8).

    ``influence.experiment.influence`` with the setup's env, agents, generator, options,
    repeats and backend (where the agents train); see it for the arguments. ``algo`` None: ``spec.default_algorithm``;
    ``confirm``: fresh episodes per selected world, only those that keep the property trained on (0: the raw selection).

    Returns:
        The content of ``run_dir/influence.json``.
    """
    from worldagent.influence.experiment import influence as run

    return run(
        run_dir,
        setup.spec,
        setup.env,
        setup.params,
        setup.policy,
        setup.generator,
        selection,
        options=dict(setup.options),
        algo=algo,
        episodes=episodes,
        seeds=seeds,
        candidates=candidates,
        search_budget=search_budget,
        search=search,
        eval_worlds=eval_worlds,
        repeats=setup.repeats,
        config=config,
        seed=seed,
        greedy=greedy,
        progress=progress,
        runs_per_program=runs_per_program,
        rounds=rounds,
        backend=setup.backend,
        confirm=confirm,
    )


def example_worlds(run_dir: str | Path, spec: EnvSpec | str, count: int = 4) -> Any:
    """Up to ``count`` influenced worlds spread over the first selected metric (Figure 8, right), batched."""
    from worldagent.influence.cache import load_influenced_worlds
    from worldagent.influence.worlds import example_indices

    worlds, _, values = load_influenced_worlds(run_dir, spec)
    picks = example_indices(values, count)
    return jax.tree_util.tree_map(lambda leaf: np.asarray(leaf)[picks], worlds)


# -- failure probability -------------------------------------------------------------------------


def failure_rate(
    store: RunStore,
    setup: Setup,
    event: str,
    *,
    method: str = "both",
    worlds: int = 10_000,
    importance: Any = None,
    target_width: float | None = None,
    seed: int = 0,
    progress: bool = True,
    say: Any = None,
) -> dict[str, Any]:
    """P(event) for worlds G(z), z ~ N(0, I), by Monte Carlo and/or importance sampling (DESIGN.md "Failure probability").

    Each estimate is one campaign of the store (``analysis.failure_rate.campaign_name``), so a
    rerun resumes it and a finished one evaluates nothing new.

    Args:
        store: the run store; ``setup``: env, agents, generator, repeats, backend.
        event: a selection such as ``"crash_rate > 0.5"`` (``worldagent.events``).
        method: "mc", "is" or "both".
        worlds: Monte Carlo's worlds, and importance sampling's worlds after its search (at most,
            with ``target_width``).
        importance: an ``analysis.failure_rate.ImportanceConfig`` (None: the defaults).
        target_width: stop once the 95% interval is within ±target_width · P.
        seed: seed of the latents and episodes.
        say: called with a line before a cost is spent (the pool's describing) or a fallback.

    Returns:
        {method: ``Estimate``} for "mc" and/or "is" (``analysis.stored.estimate_campaign``).
    """
    from worldagent.analysis import failure_rate as fr
    from worldagent.analysis import stored
    from worldagent.events import parse_selection

    importance = importance or fr.ImportanceConfig()
    fr.check_budget(worlds, target_width, importance)
    selection = parse_selection(event, setup.spec.name)
    common = dict(worlds=worlds, importance=importance, target_width=target_width, seed=seed, progress=progress, say=say)
    return {name: stored.estimate_campaign(store, setup, selection, name, **common) for name in fr.methods(method)}
