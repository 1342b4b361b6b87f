"""Influencing agents: retrain on worlds with a desired property and compare (paper §4.1, §6.2).

The paper's two iterations through its phases (§4.1): worlds are generated and the given agent
is evaluated on them (and, optionally, an optimiser searches for more worlds with the
property); the worlds that have it become a new training distribution; fresh agents are
trained on it and on the default distribution G(z) with the same algorithm, budget and seed;
both are evaluated on the same random worlds (Figure 8). Every step is cached in the run
directory, so a rerun skips finished work and a killed run resumes::

    run_dir/plan.json                the settings the cached work was made with
    run_dir/store.sqlite             every evaluated world: candidates, search, evaluations
    run_dir/influenced_worlds.npz    the new training distribution (worlds, latents, values)
    run_dir/agents/{default,influenced}-s{seed}/   trainer run dirs (+ trained.json when done)
    run_dir/influence.json           config, counts, per-seed and summary numbers, timings
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from worldagent.errors import WorldagentError
from worldagent.files import write_atomically, write_text
from worldagent.influence.selection import Selection, parse_selection

CANDIDATES = "influence-candidates"
SEARCH = "influence-search"
RESULT_FILE = "influence.json"
PLAN_FILE = "plan.json"
WORLDS_FILE = "influenced_worlds.npz"
TRAINED_FILE = "trained.json"
LABELS = ("default", "influenced")
RANDOM_BATCH = 250  # latents per round of the random campaigns (fixed: it shapes their replay)
ALGORITHMS = {"racing": ("acktr", "ppo"), "harvest": ("dqn",)}

# The metrics Figure 8 compares (raw and, for racing, normalised reward; crash / lap rates).
COMPARED = {
    "racing": ("return", "normalised_return", "crashed", "lap_completed"),
    "harvest": ("group_reward", "conflict", "equality"),
}


# -- selecting worlds ----------------------------------------------------------------------------


def world_type(env_name: str) -> type:
    """The world dataclass of ``env_name`` (to rebuild worlds from the store's arrays)."""
    if env_name == "racing":
        from worldagent.envs.racing.world import Track

        return Track
    if env_name == "harvest":
        from worldagent.envs.harvest.world import HarvestMap

        return HarvestMap
    raise WorldagentError(f"unknown environment {env_name!r}; use racing or harvest.")


def stack_worlds(env_name: str, worlds: Sequence[dict]) -> Any:
    """One batched world pytree (leading axis n) from n stored worlds (dicts of arrays)."""
    kind = world_type(env_name)
    fields = [f.name for f in dataclasses.fields(kind)]
    return kind(**{name: np.stack([np.asarray(w[name]) for w in worlds]) for name in fields})


def select_worlds(store, campaign_names: Sequence[str], selection: Selection | str, env_name: str) -> tuple[Any, np.ndarray, dict[str, np.ndarray]]:
    """Every evaluated world of the campaigns that has the property (paper §6.2).

    Args:
        store: a ``RunStore``.
        campaign_names: the campaigns whose worlds to consider.
        selection: a ``Selection`` (or its text).
        env_name: "racing" or "harvest".

    Returns:
        (worlds: batched world pytree [k], latents f64[k, dim], {metric: f64[k] per-world means}).

    Raises:
        WorldagentError: when no world matches, saying how many were tried and the range each
            selected metric took on them (so the threshold can be moved), or when the
            campaigns hold no worlds.
    """
    selection = (parse_selection(selection, env_name) if isinstance(selection, str) else selection).resolve(env_name)
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
    return stack_worlds(env_name, [evaluations[i].world for i in kept]), latents, {m: v[kept] for m, v in means.items()}


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


# -- configuration and caching -------------------------------------------------------------------


def training_config(env_name: str, algo: str, episodes: int | None, config: Any = None, tagger: int | None = None) -> Any:
    """The run's training config: ``config`` (default: the algorithm's paper defaults) with the
    budget set to ``episodes`` and, for harvest, the tagging agent (seeds are set per run)."""
    if env_name not in ALGORITHMS:
        raise WorldagentError(f"unknown environment {env_name!r}; use racing or harvest.")
    if algo not in ALGORITHMS[env_name]:
        raise WorldagentError(f"unknown algorithm {algo!r} for {env_name}; use one of: {', '.join(ALGORITHMS[env_name])}.")
    if episodes is not None and (isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) or episodes < 1):
        raise WorldagentError(f"episodes={episodes!r}; train for at least one episode.")
    if env_name == "racing":
        from worldagent.agents.acktr import ACKTRConfig
        from worldagent.agents.ppo import PPOConfig

        kind = {"acktr": ACKTRConfig, "ppo": PPOConfig}[algo]
        config = kind() if config is None else config
        if not isinstance(config, kind):
            raise WorldagentError(f"algorithm {algo!r} takes a {kind.__name__}, not a {type(config).__name__}.")
        if tagger is not None:
            raise WorldagentError("tagger applies to harvest only.")
        return config if episodes is None else dataclasses.replace(config, total_episodes=int(episodes))
    from worldagent.agents.dqn import DQNConfig

    config = DQNConfig() if config is None else config
    if not isinstance(config, DQNConfig):
        raise WorldagentError(f"algorithm 'dqn' takes a DQNConfig, not a {type(config).__name__}.")
    config = dataclasses.replace(config, tagger=tagger, **({} if episodes is None else {"num_episodes": int(episodes)}))
    config.validate()
    return config


def config_dict(config: Any) -> dict:
    """A training config as JSON-able fields."""
    if hasattr(config, "to_dict"):
        return config.to_dict()
    from worldagent.agents.dqn_run import config_to_dict

    return config_to_dict(config)


def fingerprint(tree: Any, name: str = "") -> str:
    """Short SHA-256 of a pytree's leaves (shapes, dtypes, bytes) and a name: which agent / G made the cache."""
    digest = hashlib.sha256(name.encode())
    for leaf in jax.tree_util.tree_leaves(tree):
        if hasattr(leaf, "dtype") and jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
            leaf = jax.random.key_data(leaf)
        array = np.asarray(leaf)
        digest.update(f"{array.shape}{array.dtype}".encode())
        digest.update(np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()[:16]


def check_plan(run_dir: Path, stage: str, settings: dict) -> None:
    """Record the settings one stage's cached work is made with (``plan.json``), or refuse a run
    dir whose cached work of that stage was made with other settings.

    Two stages: "worlds" (the candidates: agent, G, env params, counts, seed; checked first) and
    "training" (the selection, algorithm and budget; recorded only once a selection matched, so
    a selection that matched nothing can be loosened and rerun in the same directory).
    """
    path = run_dir / PLAN_FILE
    try:
        plan = json.loads(path.read_text()) if path.is_file() else {}
    except ValueError:
        raise WorldagentError(f"{path} is not valid JSON; delete it or use another output directory.") from None
    wanted = json.loads(json.dumps(settings))  # compare as stored: tuples become lists
    previous = plan.get(stage, wanted)
    differing = sorted(k for k in wanted.keys() | previous.keys() if previous.get(k) != wanted.get(k))
    if differing:
        raise WorldagentError(
            f"{run_dir} holds an influence run made with other settings ({', '.join(differing)}); "
            "rerun with the same ones or use another output directory (--out)."
        )
    if stage not in plan:
        write_text(path, json.dumps({**plan, stage: settings}, indent=1, sort_keys=True))


def search_target(selection: Selection) -> str:
    """What a search pushes toward (part of the "worlds" stage when there is a search)."""
    clause = selection.clauses[0]
    direction = "max" if clause.op in (">", ">=") else "min" if clause.op in ("<", "<=") else f"{clause.op} {clause.number:g}"
    return f"{clause.metric} {direction}"


def save_influenced_worlds(path: Path, worlds: Any, latents: np.ndarray, values: dict[str, np.ndarray]) -> Path:
    """The influenced distribution as ``.npz``: ``world_<field>`` arrays, ``latents``, ``value_<metric>``."""
    arrays = {f"world_{k}": np.asarray(v) for k, v in vars(worlds).items()}
    arrays.update({"latents": np.asarray(latents)}, **{f"value_{k}": np.asarray(v) for k, v in values.items()})

    def save(tmp: Path) -> None:
        with open(tmp, "wb") as handle:
            np.savez_compressed(handle, **arrays)

    return write_atomically(path, save)


def load_influenced_worlds(run_dir: str | Path, env_name: str) -> tuple[Any, np.ndarray, dict[str, np.ndarray]]:
    """(worlds [k], latents f64[k, dim], {metric: f64[k]}) of a run's influenced distribution."""
    path = Path(run_dir) / WORLDS_FILE
    if not path.is_file():
        raise WorldagentError(f"{path} does not exist; run `worldagent influence` into {run_dir} first.")
    with np.load(path, allow_pickle=False) as data:
        world = {k[len("world_") :]: data[k] for k in data.files if k.startswith("world_")}
        values = {k[len("value_") :]: data[k] for k in data.files if k.startswith("value_")}
        latents = data["latents"]
    fields = [f.name for f in dataclasses.fields(world_type(env_name))]
    if sorted(world) != sorted(fields):
        raise WorldagentError(f"{path} holds no {env_name} worlds; pass the environment the run was made for.")
    return world_type(env_name)(**world), latents, values


def example_indices(values: dict[str, np.ndarray], count: int = 4) -> np.ndarray:
    """Up to ``count`` worlds spread evenly over the first selected metric's range (Figure 8, right)."""
    first = np.asarray(next(iter(values.values())))
    order = np.argsort(first, kind="stable")
    picks = np.unique(np.round(np.linspace(0, len(order) - 1, min(count, len(order)))).astype(int))
    return order[picks]


# -- steps -----------------------------------------------------------------------------------------


def evaluate_campaign(store, spec, objective, env, policy, G, params, repeats: int, keep_worlds: bool, progress: bool) -> list:
    """Run (or resume) one campaign of ``policy`` on G(z) worlds; returns its evaluations."""
    from worldagent.search.campaign import run_campaign
    from worldagent.search.objectives import LatentObjective

    evaluate = LatentObjective(objective, env, policy, G, repeats, params, keep_worlds=keep_worlds)
    return run_campaign(store, spec, evaluate, resume=True, progress=progress)


def train_agent(
    out: Path, env_name: str, algo: str, config: Any, distribution: Any, seed: int, env: Any, params: Any, spec: str, progress: bool
) -> dict:
    """Train one agent into ``out`` (resuming its checkpoint), or return the record of a finished one.

    A finished agent is marked by ``trained.json`` (written after the trainer returns), so a
    rerun neither compiles nor rewrites it.
    """
    marker = out / TRAINED_FILE
    if marker.is_file():
        return json.loads(marker.read_text())
    if env_name == "racing":
        from worldagent.agents.training import train_racing

        result = train_racing(
            config, distribution, out, algo, seed=seed, env=env, env_params=params, progress=progress, resume=True, distribution_spec=spec
        )
        record = {"policy": "policy", "episodes": result.episodes, "env_steps": result.env_steps, "wall_seconds": round(result.wall_seconds, 3)}
    else:
        from worldagent.agents.dqn_run import train_harvest

        run_config = dataclasses.replace(config, seed=int(seed))
        result = train_harvest(run_config, distribution, out, progress=progress, resume=True)
        record = {
            "policy": "agents",
            "episodes": run_config.num_chunks * run_config.num_envs,
            "env_steps": result.env_steps,
            "wall_seconds": round(result.wall_s, 3),
        }
    write_text(marker, json.dumps({**record, "seed": int(seed), "distribution": spec}, indent=1))
    return json.loads(marker.read_text())


def trained_policies(agent_dirs: dict[str, Path], env_name: str, greedy: bool) -> dict[str, Any]:
    """Each trained agent as a ``Policy``; agents of one architecture share one ``act`` (one compilation)."""
    from worldagent.agents.policy import load_policy

    policies, template = {}, None
    for label, directory in agent_dirs.items():
        saved = load_policy(directory, env=env_name, greedy=greedy)
        same = template is not None and (saved.module, saved.kind, saved.extra.get("act_epsilon")) == template[0]
        policies[label] = template[1].replace(params=saved.params) if same else saved.policy
        if template is None:
            template = ((saved.module, saved.kind, saved.extra.get("act_epsilon")), saved.policy)
    return policies


def episode_values(evaluations: Sequence, metric: str) -> np.ndarray:
    """f64[worlds, repeats] of one metric from a campaign's evaluations."""
    return np.asarray([[float(np.nan if e[metric] is None else e[metric]) for e in ev.episodes] for ev in evaluations], np.float64)


def mean_and_ci(values: Sequence[float], level: float = 0.95) -> dict:
    """Mean over seeds and the half-width of its Student-t confidence interval (NaN with one seed:
    one seed says nothing about the spread between seeds)."""
    values = np.asarray(values, np.float64)
    n = len(values)
    if n < 2:
        return {"mean": float(values.mean()) if n else float("nan"), "ci95": float("nan"), "seeds": n}
    from scipy.stats import t  # scipy comes with bayesian-optimization (scikit-learn)

    half = float(t.ppf(0.5 + level / 2, n - 1) * values.std(ddof=1) / np.sqrt(n))
    return {"mean": float(values.mean()), "ci95": half, "seeds": n}


def summarise(per_seed: dict[str, dict[str, dict[str, float]]], metrics: Sequence[str]) -> dict:
    """{metric: {label: mean_and_ci over seeds}} from {label: {seed: {metric: value}}}."""
    return {m: {label: mean_and_ci([row[m] for row in runs.values()]) for label, runs in per_seed.items()} for m in metrics}


def _json_safe(value: Any) -> Any:
    """NaN and infinities as null (strict JSON), recursively."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


# -- the experiment --------------------------------------------------------------------------------


def influence(
    run_dir: str | Path,
    env_name: str,
    agent_policy: Any,
    G: Any,
    params: Any,
    selection: Selection | str,
    *,
    algo: str,
    episodes: int | None,
    seeds: Sequence[int] = (0, 1, 2),
    candidates: int = 500,
    search_budget: int = 0,
    eval_worlds: int = 200,
    repeats: int = 8,
    tagger: int | None = None,
    progress: bool = True,
    config: Any = None,
    env: Any = None,
    seed: int = 0,
    greedy: bool = False,
) -> dict:
    """Influence agents: train on worlds with a property, compare with default training (paper §6.2).

    Args:
        run_dir: where every step is cached (see the module docstring); rerun to resume.
        env_name: "racing" or "harvest".
        agent_policy: the agent whose behaviour defines the property (a ``Policy``).
        G: the generator (``worlds.generator.Generator``).
        params: env parameters of every evaluation and (racing) of training; harvest agents
            train on their ``DQNConfig``'s own parameters, so pass matching ones (tagger, length).
        selection: the property (a ``Selection`` or text, e.g. ``"crash_rate > 0.5"``).
        algo: racing "acktr" or "ppo"; harvest "dqn".
        episodes: training episodes of every agent (None: the config's budget).
        seeds: one default and one influenced agent per seed; the summary is over seeds.
        candidates: random G(z) worlds evaluated with ``agent_policy`` (step a).
        search_budget: worlds a CMA-ES search evaluates on top, pushing the selection's first
            metric toward the property (the paper's second iteration, §4.1); 0: none.
        eval_worlds: random G(z) worlds every trained agent is evaluated on (the same for all).
        repeats: episodes per world, for candidates and evaluation (the paper: 8).
        tagger: harvest: the agent allowed to TAG (§6.2.2: 0).
        progress: progress bars.
        config: base training config (``PPOConfig``/``ACKTRConfig``/``DQNConfig``; default the
            algorithm's defaults); its budget is replaced by ``episodes``, its seed by each seed.
        env: the env object (default: ``ParticleRacing()``, or the ``DQNConfig``'s harvest window).
        seed: seed of the candidates, the search and the evaluation worlds (the latter use
            ``seed + 1``, so they are fresh worlds of the same distribution).
        greedy: trained actor-critics act by argmax when evaluated.

    Returns:
        The content of ``run_dir/influence.json`` (with NaN where the file has null).
    """
    from worldagent.agents.distributions import LatentWorlds, WorldPool
    from worldagent.search.campaign import CampaignSpec
    from worldagent.search.objectives import Objective, metric_name
    from worldagent.search.optimisers import OptimiserConfig
    from worldagent.store import RunStore

    started = time.perf_counter()
    selection = (parse_selection(selection, env_name) if isinstance(selection, str) else selection).resolve(env_name)
    config = training_config(env_name, algo, episodes, config, tagger)
    seeds = [int(s) for s in seeds]
    _check_counts(seeds, candidates, search_budget, eval_worlds, repeats)
    if getattr(G, "env", env_name) != env_name:
        raise WorldagentError(f"the generator makes {G.env} worlds, not {env_name} worlds; pass a {env_name} generator.")
    env = env if env is not None else _default_env(env_name, config)
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    check_plan(
        run_dir,
        "worlds",
        {
            "env": env_name,
            "candidates": int(candidates),
            "search_budget": int(search_budget),
            "repeats": int(repeats),
            "seed": int(seed),
            "search": search_target(selection) if search_budget > 0 else None,
            "agent": fingerprint(agent_policy, getattr(agent_policy, "name", "")),
            "generator": fingerprint(G, f"{G.env} {getattr(G, 'apples', 0)}"),
            "params": fingerprint(params),
        },
    )
    metric = selection.metrics[0]
    timings: dict[str, Any] = {}
    with RunStore(run_dir) as store:
        # (a) candidate worlds: random G(z), then optionally a search for more with the property
        clock = time.perf_counter()
        random_spec = CampaignSpec(
            CANDIDATES, env_name, metric, True, "random", int(candidates), int(seed), G.latent_dim, OptimiserConfig(random_batch=RANDOM_BATCH)
        )
        tried = evaluate_campaign(store, random_spec, Objective(env_name, metric, True), env, agent_policy, G, params, repeats, True, progress)
        timings["candidates"] = time.perf_counter() - clock
        campaigns = [CANDIDATES]
        if search_budget > 0:
            clock = time.perf_counter()
            maximize = search_direction(selection, selection.world_means(tried)[metric])
            search_spec = CampaignSpec(SEARCH, env_name, metric, maximize, "cmaes", int(search_budget), int(seed), G.latent_dim)
            tried = tried + evaluate_campaign(
                store, search_spec, Objective(env_name, metric, maximize), env, agent_policy, G, params, repeats, True, progress
            )
            campaigns.append(SEARCH)
            timings["search"] = time.perf_counter() - clock
        # (b) the influenced distribution: the matching worlds, uniformly
        worlds, latents, values = select_worlds(store, campaigns, selection, env_name)
        check_plan(run_dir, "training", {"selection": selection.describe(), "algo": algo, "training": config_dict(config), "greedy": bool(greedy)})
        save_influenced_worlds(run_dir / WORLDS_FILE, worlds, latents, values)
        distributions = {
            "default": (LatentWorlds(G), "G(z), z ~ N(0, I)"),
            "influenced": (WorldPool.create(worlds), f"{len(latents)} worlds with {selection.describe()}"),
        }
        # (c) one default and one influenced agent per seed, same algorithm, budget and seed
        agents, agent_dirs, timings["train"] = {}, {}, {}
        for s in seeds:
            for label in LABELS:
                name = f"{label}-s{s}"
                clock = time.perf_counter()
                distribution, spec = distributions[label]
                agents[name] = train_agent(run_dir / "agents" / name, env_name, algo, config, distribution, s, env, params, spec, progress)
                agent_dirs[name] = run_dir / "agents" / name / agents[name]["policy"]
                timings["train"][name] = time.perf_counter() - clock
        # (d) every agent on the same random worlds, with the same episode keys
        clock = time.perf_counter()
        reward = metric_name(env_name, "reward")
        eval_spec = CampaignSpec(
            "", env_name, reward, True, "random", int(eval_worlds), int(seed) + 1, G.latent_dim, OptimiserConfig(random_batch=RANDOM_BATCH)
        )
        compared = COMPARED[env_name]
        per_seed: dict[str, dict[str, dict[str, float]]] = {label: {} for label in LABELS}
        for name, policy in trained_policies(agent_dirs, env_name, greedy).items():
            spec = dataclasses.replace(eval_spec, name=f"influence-eval-{name}-w{eval_worlds}-r{repeats}")
            evaluations = evaluate_campaign(store, spec, Objective(env_name, reward, True), env, policy, G, params, repeats, False, progress)
            label, s = name.rsplit("-s", 1)
            per_seed[label][s] = {m: float(np.nanmean(episode_values(evaluations, m))) for m in compared}
        timings["evaluate"] = time.perf_counter() - clock
    # (e) mean over seeds with a 95% Student-t interval
    timings["total"] = time.perf_counter() - started
    result = {
        "env": env_name,
        "algo": algo,
        "selection": {"text": selection.text, "describe": selection.describe(), "metrics": list(selection.metrics)},
        "config": {
            "episodes": episodes,
            "seeds": seeds,
            "candidates": int(candidates),
            "search_budget": int(search_budget),
            "eval_worlds": int(eval_worlds),
            "repeats": int(repeats),
            "tagger": tagger,
            "seed": int(seed),
            "greedy": bool(greedy),
            "training": config_dict(config),
        },
        "worlds": {
            "tried": len(tried),
            "selected": int(len(latents)),
            "campaigns": campaigns,
            "selected_values": {m: {"min": float(v.min()), "mean": float(v.mean()), "max": float(v.max())} for m, v in values.items()},
        },
        "metrics": list(compared),
        "per_seed": per_seed,
        "summary": summarise(per_seed, compared),
        "agents": {name: {**record, "dir": str(Path("agents") / name)} for name, record in agents.items()},
        "wall_seconds": _rounded(timings),
        "files": {"store": "store.sqlite", "worlds": WORLDS_FILE, "plan": PLAN_FILE},
    }
    write_text(run_dir / RESULT_FILE, json.dumps(_json_safe(result), indent=1))
    return result


def _check_counts(seeds: list[int], candidates: int, search_budget: int, eval_worlds: int, repeats: int) -> None:
    if not seeds or any(s < 0 for s in seeds) or len(set(seeds)) != len(seeds):
        raise WorldagentError(f"seeds={seeds}; pass one or more distinct non-negative seeds.")
    for name, value, least in (
        ("candidates", candidates, 1),
        ("search_budget", search_budget, 0),
        ("eval_worlds", eval_worlds, 1),
        ("repeats", repeats, 1),
    ):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
            raise WorldagentError(f"{name}={value!r}; pass an integer of at least {least}.")


def _default_env(env_name: str, config: Any) -> Any:
    """Racing: ``ParticleRacing()``; harvest: the env of the DQN config's observation window."""
    if env_name == "racing":
        from worldagent.envs.racing.env import ParticleRacing

        return ParticleRacing()
    return config.env()


def _rounded(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    return round(float(value), 3)
