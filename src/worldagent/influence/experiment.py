"""Influencing agents: retrain on worlds with a desired property and compare (paper §4.1, §6.2).

The paper's two iterations through its phases (§4.1): worlds are generated and the given agent
is evaluated on them (and, optionally, an optimiser searches for more worlds with the
property); the worlds that have it become a new training distribution; fresh agents are
trained on it and on the default distribution G(z) with the same algorithm, budget and seed;
both are evaluated on the same random worlds (Figure 8). Every step is cached in the run
directory (``influence.cache``), so a rerun skips finished work and a killed run resumes::

    run_dir/plan.json                the settings the cached work was made with
    run_dir/store.sqlite             every evaluated world: candidates, search, evaluations
    run_dir/influenced_worlds.npz    the new training distribution (worlds, latents, values)
    run_dir/agents/{default,influenced}-s{seed}/   trainer run dirs (+ trained.json when done)
    run_dir/influence.json           config, counts, per-seed and summary numbers, timings

Everything about the environment comes from its spec: the metrics compared
(``spec.metrics.compared``), the default algorithm, and how its worlds are stored.
"""

from __future__ import annotations

import dataclasses
import json
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from worldagent.agents.policy import agent_record
from worldagent.errors import WorldagentError
from worldagent.events import Selection
from worldagent.files import write_text
from worldagent.influence.cache import PLAN_FILE, WORLDS_FILE, check_plan, config_dict, fingerprint, save_influenced_worlds
from worldagent.influence.confirmation import check_confirm, confirm_selection, none_survived
from worldagent.influence.statistics import episode_values, json_safe, rounded, summarise
from worldagent.influence.training import LABELS, check_runs_per_program, train_all
from worldagent.influence.worlds import resolved, search_direction, search_target, selected_evaluations, stacked

CANDIDATES = "influence-candidates"
SEARCH = "influence-search"
RESULT_FILE = "influence.json"
RANDOM_BATCH = 250  # latents per round of the random campaigns (fixed: it shapes their replay)


def compared_metrics(spec) -> tuple[str, ...]:
    """The metrics Figure 8 compares: the spec's ``compared``, else its main metric."""
    return tuple(spec.metrics.compared) or (spec.metrics.main,)


SEARCHES = ("cmaes", "atlas")  # how step (b) searches: CMA-ES (the paper's optimiser) or a CMA-ME atlas (distinct worlds)


def evaluate_campaign(
    store, campaign, objective, env, policy, G, params, repeats: int, keep_worlds: bool, progress: bool, optimiser: Any = None
) -> list:
    """Run (or resume) one campaign of ``policy`` on G(z) worlds (``optimiser``: a prebuilt one); returns its evaluations."""
    from worldagent.search.campaign import run_campaign
    from worldagent.search.objectives import LatentObjective

    evaluate = LatentObjective(objective, env, policy, G, repeats, params, keep_worlds=keep_worlds)
    campaign = dataclasses.replace(campaign, agent=agent_record(policy))
    return run_campaign(store, campaign, evaluate, resume=True, progress=progress, optimiser=optimiser)


def trained_policies(agent_dirs: dict[str, Path], spec, greedy: bool) -> dict[str, Any]:
    """Each trained agent as a ``Policy``.

    The agents of one run share algorithm and config, so agents whose parameters have the same
    structure and shapes share the first one's ``act`` too: one compilation instead of one each.
    """
    from worldagent.agents.saved import load_policy

    policies, template = {}, None
    for label, directory in agent_dirs.items():
        policy = load_policy(directory, env=spec.name, greedy=greedy).policy
        shape = (
            policy.name,
            jax.tree_util.tree_structure(policy.params),
            [(np.shape(x), str(getattr(x, "dtype", type(x).__name__))) for x in jax.tree_util.tree_leaves(policy.params)],
        )
        if template is not None and template[0] == shape:
            policy = template[1].replace(params=policy.params)
        elif template is None:
            template = (shape, policy)
        policies[label] = policy
    return policies


def _check_counts(seeds: list[int], episodes, candidates: int, search_budget: int, eval_worlds: int, repeats: int) -> None:
    if not seeds or any(s < 0 for s in seeds) or len(set(seeds)) != len(seeds):
        raise WorldagentError(f"seeds={seeds}; pass one or more distinct non-negative seeds.")
    if episodes is not None and (isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) or episodes < 1):
        raise WorldagentError(f"episodes={episodes!r}; train for at least one episode.")
    for name, value, least in (
        ("candidates", candidates, 1),
        ("search_budget", search_budget, 0),
        ("eval_worlds", eval_worlds, 1),
        ("repeats", repeats, 1),
    ):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
            raise WorldagentError(f"{name}={value!r}; pass an integer of at least {least}.")


def _check_algorithm(spec, algo: str | None) -> str:
    """``algo``, or the env's default; one the env trains with."""
    algo = algo or spec.default_algorithm
    if algo not in spec.algorithms:
        raise WorldagentError(f"unknown algorithm {algo!r} for {spec.name}; use one of: {', '.join(spec.algorithms)}.")
    return algo


def find_worlds(store, spec, env, params, policy, G, selection: Selection, counts: dict, progress: bool, backend: Any = None):
    """Steps (a) and (b): candidate worlds, an optional search, and those with the property; with
    ``counts["confirm"]`` > 0 only those that keep it on that many fresh episodes (``influence.confirmation``).

    Returns:
        (evaluations tried, campaign names, worlds [k], latents f64[k, dim], {metric: f64[k] as found},
        the confirmation's summary or None, timings).
    """
    tried, campaigns, timings = search_worlds(store, spec, env, params, policy, G, selection, counts, progress)
    picks, confirmation = selected_evaluations(store, campaigns, selection, spec), None
    if counts.get("confirm"):
        clock = time.perf_counter()
        setup = selecting_setup(spec, env, params, policy, G, counts, backend)
        picks, confirmation = confirm_selection(
            store,
            setup,
            picks,
            selection,
            repeats=counts["confirm"],
            seed=counts["seed"],
            name=f"influence:{selection.text}",
            failure=failure_event(spec),
            progress=progress,
        )
        timings["confirm"] = time.perf_counter() - clock
        if not picks:
            raise none_survived(confirmation, selection)
    worlds, latents, values = stacked(picks, selection, spec)
    return tried, campaigns, worlds, latents, values, confirmation, timings


def selecting_setup(spec, env, params, policy, G, counts: dict, backend: Any = None):
    """The ``experiments.Setup`` of the agent that selects the worlds (what a confirmation replays)."""
    from worldagent.experiments import Setup

    return Setup(spec, env, params, policy, G, counts["repeats"], counts.get("options", {}), backend)


def failure_event(spec) -> Selection | None:
    """The env's failure event (``spec.failure``), resolved; None where the env has none."""
    return resolved(spec.failure, spec) if spec.failure else None


def search_worlds(store, spec, env, params, policy, G, selection: Selection, counts: dict, progress: bool, names=(CANDIDATES, SEARCH)):
    """Evaluate ``policy`` on the candidates and run the optional search, as the campaigns ``names``
    (candidates, search); returns (evaluations tried, campaign names, timings)."""
    from worldagent.search.campaign import CampaignSpec
    from worldagent.search.objectives import Objective
    from worldagent.search.optimisers import OptimiserConfig

    metric, seed, repeats, timings = selection.metrics[0], counts["seed"], counts["repeats"], {}
    clock = time.perf_counter()
    random_spec = CampaignSpec(
        names[0], spec.name, metric, True, "random", counts["candidates"], seed, G.latent_dim, OptimiserConfig(random_batch=RANDOM_BATCH)
    )
    tried = evaluate_campaign(store, random_spec, Objective(spec.name, metric, True), env, policy, G, params, repeats, True, progress)
    timings["candidates"] = time.perf_counter() - clock
    campaigns = [names[0]]
    if counts["search_budget"] > 0:
        clock = time.perf_counter()
        maximize = search_direction(selection, selection.world_means(tried)[metric])
        optimiser, extra, name = None, None, "cmaes"
        if counts.get("search") == "atlas":  # the best world of every cell: many distinct worlds with the property, not one corner
            from worldagent.search.atlas import atlas_optimiser

            optimiser, extra = atlas_optimiser(spec, G, maximize, seed, counts["search_budget"])
            name = optimiser.name
        search_spec = CampaignSpec(names[1], spec.name, metric, maximize, name, counts["search_budget"], seed, G.latent_dim, extra=extra)
        objective = Objective(spec.name, metric, maximize)
        tried = tried + evaluate_campaign(store, search_spec, objective, env, policy, G, params, repeats, True, progress, optimiser)
        campaigns.append(names[1])
        timings["search"] = time.perf_counter() - clock
    return tried, campaigns, timings


def compare_agents(
    store, spec, env, params, G, policies: dict, counts: dict, progress: bool, prefix: str = ""
) -> dict[str, dict[str, dict[str, float]]]:
    """Step (d): every agent on the same random worlds with the same episode keys; {label: {seed: {metric: mean}}}.

    ``policies``: {"influenced-s0": policy, ...}; ``prefix`` sets a round's evaluation campaigns apart.
    """
    from worldagent.search.campaign import CampaignSpec
    from worldagent.search.objectives import Objective
    from worldagent.search.optimisers import OptimiserConfig

    worlds, repeats, main = counts["eval_worlds"], counts["repeats"], spec.metrics.main
    base = CampaignSpec("", spec.name, main, True, "random", worlds, counts["seed"] + 1, G.latent_dim, OptimiserConfig(random_batch=RANDOM_BATCH))
    per_seed: dict[str, dict[str, dict[str, float]]] = {label: {} for label in LABELS}
    for name, policy in policies.items():
        campaign = dataclasses.replace(base, name=f"influence-eval-{prefix}{name}-w{worlds}-r{repeats}")
        evaluations = evaluate_campaign(store, campaign, Objective(spec.name, main, True), env, policy, G, params, repeats, False, progress)
        label, s = name.rsplit("-s", 1)
        per_seed[label][s] = {m: float(np.nanmean(episode_values(evaluations, m))) for m in compared_metrics(spec)}
    return per_seed


def training_failures(spec, per_seed: dict) -> dict[str, str]:
    """{"influenced-s2": why} for every trained agent ``spec.training_check`` says did not learn."""
    if spec.training_check is None:
        return {}
    found = {f"{label}-s{seed}": spec.training_check(means) for label, by_seed in per_seed.items() for seed, means in by_seed.items()}
    return {name: why for name, why in found.items() if why}


def influence(
    run_dir: str | Path,
    spec,
    env: Any,
    params: Any,
    policy: Any,
    G: Any,
    selection: Selection | str,
    *,
    options: dict | None = None,
    algo: str | None = None,
    episodes: int | None = None,
    seeds: Sequence[int] = (0, 1, 2),
    candidates: int = 500,
    search_budget: int = 0,
    search: str = "cmaes",
    eval_worlds: int = 200,
    repeats: int = 8,
    config: Any = None,
    seed: int = 0,
    greedy: bool = False,
    progress: bool = True,
    runs_per_program: int | None = None,
    rounds: int = 1,
    backend: Any = None,
    confirm: int = 0,
) -> dict:
    """Influence agents: train on worlds with a property, compare with default training (paper §6.2).

    ``experiments.influence(run_dir, setup, selection, ...)`` is the usual entry point; this is
    the same with the setup's parts spelled out.

    Args:
        run_dir: where every step is cached (see the module docstring); rerun to resume.
        spec: the env's ``EnvSpec``; ``env``, ``params``: the env object and the parameters of
            every evaluation (``spec.make_env(options)``).
        policy: the agent whose behaviour defines the property (a ``Policy``).
        G: the generator (``worlds.generator.Generator``) of ``spec``'s worlds.
        selection: the property (a ``Selection`` or text, e.g. ``"crash_rate > 0.5"``).
        options: the env options the agents train with (harvest: ``{"tagger": (0,)}``).
        algo: the training algorithm (default ``spec.default_algorithm``).
        episodes: training episodes of every agent (None: the config's budget).
        seeds: one default and one influenced agent per seed; the summary is over seeds.
        candidates: random G(z) worlds evaluated with ``policy`` (step a).
        search_budget: worlds a CMA-ES search evaluates on top, pushing the selection's first
            metric toward the property (the paper's second iteration, §4.1); 0: none.
        search: "cmaes" (the paper's optimiser; it tends to revisit one world) or "atlas" (CMA-ME
            over the spec's default descriptors: the most extreme world of every cell, so the
            selected worlds are many distinct ones).
        eval_worlds: random G(z) worlds every trained agent is evaluated on (the same for all).
        repeats: episodes per world, for candidates and evaluation (the paper: 8).
        config: base training config (default the algorithm's, with the env's overrides); its
            budget is replaced by ``episodes``, its seed by each seed.
        seed: seed of the candidates and the search; the evaluation worlds use ``seed + 1``.
        greedy: trained actor-critics act by argmax when evaluated.
        progress: progress bars.
        runs_per_program: agents trained as one program at most (``many.train_many``; memory);
            None: ``default_runs_per_program()``, from the device.
        rounds: the phases iterated (``influence.rounds``): after round 1 (the above), each
            round r >= 2 searches again with each seed's influenced agent of round r - 1, adds
            the worlds it selects to that seed's influenced worlds and retrains on them, kept in
            ``run_dir/round-<r>/``.
        backend: where the agents train: None here, or a Ray backend (``evaluation.backends``),
            each program of runs a task on a worker (``many.train_many``); the confirmation plays there too.
        confirm: fresh episodes each selected world is replayed on (``influence.confirmation``): only the
            worlds that keep the property on them are trained on (every round's selection alike);
            0 (the default here; the CLI's is 32): the raw selection, as found.

    Returns:
        The content of ``run_dir/influence.json`` (with NaN where the file has null); with
        ``rounds`` > 1 its "rounds" lists each later round's summary (``round-<r>/influence.json``).
    """
    from worldagent.agents.algorithms import training_config
    from worldagent.store import RunStore

    started = time.perf_counter()
    selection = resolved(selection, spec)
    algo = _check_algorithm(spec, algo)
    seeds = [int(s) for s in seeds]
    _check_counts(seeds, episodes, candidates, search_budget, eval_worlds, repeats)
    check_runs_per_program(runs_per_program)
    check_rounds(rounds)
    confirm = check_confirm(confirm)
    if search not in SEARCHES:
        raise WorldagentError(f"unknown search {search!r}; use one of: {', '.join(SEARCHES)}.")
    if G.env != spec.name:
        raise WorldagentError(f"the generator makes {G.env} worlds, not {spec.name} worlds; pass a {spec.name} generator.")
    config = training_config(spec, algo, episodes, base=config, options=options)
    counts = {
        "candidates": int(candidates),
        "search_budget": int(search_budget),
        **({"search": search} if search != "cmaes" else {}),  # absent for CMA-ES: plans made before the option still match
        "eval_worlds": int(eval_worlds),
        "repeats": int(repeats),
        "seed": int(seed),
    }
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    options = json.loads(json.dumps(spec.check_options(options), default=str))  # as stored: tuples become lists
    check_plan(
        run_dir,
        "worlds",
        {
            **{k: v for k, v in counts.items() if k != "eval_worlds"},
            "env": spec.name,
            "search": search_target(selection) if search_budget > 0 else None,
            "agent": fingerprint(policy, getattr(policy, "name", "")),
            "generator": fingerprint(G, G.env),
            "params": fingerprint(params),
        },
    )
    training_plan = {
        "selection": selection.describe(),
        **({"confirm": confirm} if confirm else {}),  # absent without confirmation: plans made before the option still match
        "algo": algo,
        "training": config_dict(config),
        "greedy": bool(greedy),
        "options": options,
    }
    check_plan(run_dir, "training", training_plan, record=False)  # refused before a confirmation it would not use
    with RunStore(run_dir) as store:
        found = {**counts, "confirm": confirm, "options": options}
        tried, campaigns, worlds, latents, values, confirmation, timings = find_worlds(
            store, spec, env, params, policy, G, selection, found, progress, backend
        )
        check_plan(run_dir, "training", training_plan)
        save_influenced_worlds(run_dir / WORLDS_FILE, spec, worlds, latents, values)
        agents, timings["train"] = train_all(
            run_dir, spec, algo, config, G, worlds, selection, seeds, options, params, progress, runs_per_program, backend
        )
        clock = time.perf_counter()
        agent_dirs = {name: run_dir / "agents" / name / record["policy"] for name, record in agents.items()}
        per_seed = compare_agents(store, spec, env, params, G, trained_policies(agent_dirs, spec, greedy), counts, progress)
        timings["evaluate"] = time.perf_counter() - clock
    timings["total"] = time.perf_counter() - started
    settings = {**counts, "episodes": episodes, "seeds": seeds, "options": options, "greedy": bool(greedy), "training": config_dict(config)}
    worlds_found = {"tried": len(tried), "selected": int(len(latents)), "campaigns": campaigns, "selected_values": value_ranges(values)}
    if confirmation is not None:  # "selected": the worlds trained on, those that survived; "selected_values" as found
        settings["confirm"] = confirm
        worlds_found |= {"raw_selected": confirmation["selected"], "confirmation": confirmation}
    result = round_result(spec, algo, selection, settings, worlds_found, per_seed, agents, "agents", timings)
    write_text(run_dir / RESULT_FILE, json.dumps(json_safe(result), indent=1))
    if rounds > 1:
        from worldagent.influence.rounds import later_rounds

        job = dict(
            spec=spec, env=env, params=params, G=G, selection=selection, algo=algo, config=config, options=options, counts=found, backend=backend
        )
        result["rounds"] = later_rounds(run_dir, job, settings, seeds, per_seed["default"], rounds, greedy, runs_per_program, progress)
        write_text(run_dir / RESULT_FILE, json.dumps(json_safe(result), indent=1))
    return result


def check_rounds(rounds: Any) -> int:
    """``rounds``: a positive integer."""
    if isinstance(rounds, bool) or not isinstance(rounds, (int, np.integer)) or rounds < 1:
        raise WorldagentError(f"rounds={rounds!r}; pass 1 (the paper's single retrain) or more (--rounds).")
    return int(rounds)


def value_ranges(values: dict[str, np.ndarray]) -> dict[str, dict[str, float]]:
    """{metric: {min, mean, max}} of the selected worlds' values."""
    return {m: {"min": float(v.min()), "mean": float(v.mean()), "max": float(v.max())} for m, v in values.items()}


def round_result(
    spec, algo: str, selection: Selection, settings: dict, worlds: dict, per_seed: dict, agents: dict, agents_dir: str, timings: dict
) -> dict:
    """What ``influence.json`` holds for one round: default against influenced agents, and how they came about."""
    compared = compared_metrics(spec)
    failed = training_failures(spec, per_seed)
    for name, why in failed.items():  # a failed run skews the comparison: say so where the user looks
        warnings.warn(f"influence: the {name} agent {why}; its seed weighs on the means and intervals.", stacklevel=3)
    return {
        "env": spec.name,
        "algo": algo,
        "selection": {"text": selection.text, "describe": selection.describe(), "metrics": list(selection.metrics)},
        "config": settings,
        "worlds": worlds,
        "metrics": list(compared),
        "per_seed": per_seed,
        "summary": summarise(per_seed, compared),
        "failed_training": failed,
        "agents": {name: {**record, "dir": str(Path(agents_dir) / name)} for name, record in agents.items()},
        "wall_seconds": rounded(timings),
        "files": {"store": "store.sqlite", "worlds": WORLDS_FILE, "plan": PLAN_FILE},
    }
