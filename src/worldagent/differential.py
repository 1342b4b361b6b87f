"""Which worlds got worse? Two agents on the same worlds, and a search for where the new one is worse (DESIGN.md "Diff").

A is the old agent, B the new one. Both play every world with the same episode keys (common
random numbers: each world's keys come from its campaign seed, generation and slot, as in every
campaign), so a difference between them is a difference of the agents, not of the dice.

- ``diff_setup``: the two agents (any kind ``--agent`` takes), each with the env options it plays.
- ``PairedObjective``: ``evaluate(z[n, dim], seeds[n]) -> [Outcome]`` for ``run_campaign``; an
  outcome's episodes hold B's metrics under their names and A's under ``A.<name>``
  (``BASELINE``), so every reader of a store sees B, and A is beside it.
- World sets, each stored as one paired campaign (a rerun resumes it): ``prior_set`` (G(z),
  z ~ N(0, I)), ``fixed_set`` (a stored campaign's worlds, datasets: ``campaign_worlds``,
  ``dataset_worlds``).
- ``differential_search``: CMA-ES or the atlas (CMA-ME over the env's descriptors) on
  metric(B) − metric(A) over z, a campaign like any other.
- ``confirm_worlds``: the worlds a diff reports (the regressed worlds of a world set, a search's
  regressed and most extreme worlds) replayed for A and for B on fresh episodes (``analysis.confirm``).
  The confirmation keys depend on the world and the seed only, so the two agents' confirmations
  play the same episodes: common random numbers again, by design (the one place two confirmations
  share keys). ``side_setup`` gives ``confirm`` one agent of a ``DiffSetup``.
- ``diff``: all of it, summarised by ``analysis.paired`` (the statistics of ``analysis.diff``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.agents.policy import agent_record
from worldagent.analysis.confirm import REPEATS
from worldagent.analysis.paired import (
    BASELINE,
    confirmed_pairs,
    distinct_firsts,
    failure_masks,
    features_of,
    pair_row,
    regressed_order,
    search_summary,
    side_of,
    summarise,
    world_digests,
)
from worldagent.envs import registry
from worldagent.envs.registry import EnvSpec
from worldagent.errors import WorldagentError
from worldagent.evaluation.backends import LocalBackend, split
from worldagent.evaluation.local import evaluate
from worldagent.identity import agent_identity
from worldagent.progress import progress_bar
from worldagent.search.campaign import CampaignSpec, Outcome, campaign_stream, run_campaign, stored_seed
from worldagent.search.objectives import episode_records, generate
from worldagent.search.optimisers import OptimiserConfig
from worldagent.search.prior import TYPICAL, prior_summary
from worldagent.store import Evaluation, RunStore

SET_BATCH = 64  # worlds of a world set evaluated (and committed) at a time
SEARCHES = ("cmaes", "atlas")
CONFIRMED_AT_MOST = 50  # distinct regressed worlds confirmed per world set or search (likeliest under the prior first)


@dataclass(frozen=True)
class Side:
    """One agent with the env it plays: ``env``, ``params`` (``spec.make_env(options)``), ``policy``, ``options``."""

    env: Any
    params: Any
    policy: Any
    options: dict


@dataclass(frozen=True)
class DiffSetup:
    """Two agents on one environment.

    Attributes:
        spec: the env's ``EnvSpec``; ``a``, ``b``: the old and the new agent (``Side``).
        generator: G(z) (None when only fixed worlds are compared).
        repeats: episodes per world (the paper: 8); ``backend``: where batches run (None: here).
    """

    spec: EnvSpec
    a: Side
    b: Side
    generator: Any = None
    repeats: int = 8
    backend: Any = None

    def records(self) -> dict:
        """{"a", "b"}: what each agent is (``policy.agent_record``), as campaigns record it."""
        return {"a": agent_record(self.a.policy), "b": agent_record(self.b.policy)}


@dataclass(frozen=True)
class SideSetup:
    """One agent of a ``DiffSetup`` in the shape ``analysis.confirm.confirm`` takes (``experiments.Setup``'s fields)."""

    spec: EnvSpec
    env: Any
    params: Any
    policy: Any
    generator: Any
    repeats: int
    options: dict
    backend: Any = None


def side_setup(setup: DiffSetup, which: str) -> SideSetup:
    """Agent ``which`` ("a" or "b") of ``setup`` with the env it plays, its generator and backend."""
    one = {"a": setup.a, "b": setup.b}[which]
    return SideSetup(setup.spec, one.env, one.params, one.policy, setup.generator, setup.repeats, one.options, setup.backend)


def side(spec: EnvSpec, agent: Any, options: dict | None, greedy: bool, stochastic: bool) -> Side:
    """One agent (a ``Policy``/``HostPolicy`` or text ``load_agent`` reads) with the options it plays."""
    from worldagent.agents.loaders import agent_options, load_agent

    played = agent_options(spec, agent, options)
    env, params = spec.make_env(played)
    policy = load_agent(spec, agent, greedy, played, stochastic) if isinstance(agent, (str, Path)) else agent
    return Side(env, params, policy, played)


def diff_setup(
    env: str | EnvSpec,
    agent_a: Any,
    agent_b: Any,
    generator: Path | str | Any = None,
    *,
    options: dict | None = None,
    greedy: bool = False,
    stochastic: bool = False,
    repeats: int = 8,
    backend: Any = None,
) -> DiffSetup:
    """Resolve two agents and (optionally) a generator for ``env``, one line on any mismatch.

    Args:
        env: a registered env's name or spec.
        agent_a, agent_b: the old and the new agent: ``Policy``/``HostPolicy`` objects or what
            ``--agent`` takes (a train run, ``scripted/NAME``, ``.onnx``, SB3 ``.zip``, ``module:function``).
        generator: a ``Generator``, its directory, or None (fixed worlds only).
        options: env options given (each saved agent fills the rest with its own, then the defaults).
        greedy, stochastic: as ``experiments.setup``; repeats: episodes per world; backend: where batches run.
    """
    spec = registry.get(env)
    if isinstance(repeats, bool) or not isinstance(repeats, (int, np.integer)) or repeats < 1:
        raise WorldagentError(f"repeats={repeats!r}; play at least one episode per world.")
    if isinstance(generator, (str, Path)):
        from worldagent.worlds.generator import load_generator

        where, generator = generator, load_generator(generator, env=spec.name)[0]
        if generator.env != spec.name:
            raise WorldagentError(f"the generator in {where} makes {generator.env} worlds; pass a {spec.name} generator.")
    elif generator is not None and generator.env != spec.name:
        raise WorldagentError(f"the generator makes {generator.env} worlds; pass a {spec.name} generator.")
    a, b = (side(spec, agent, options, greedy, stochastic) for agent in (agent_a, agent_b))
    return DiffSetup(spec, a, b, generator, int(repeats), backend)


# -- paired evaluation ----------------------------------------------------------------------------


def paired_episodes(metrics_a: dict, metrics_b: dict, world: int) -> list[dict]:
    """World ``world``'s episodes: B's metrics under their names, A's under ``A.<name>``."""
    records_a, records_b = episode_records(metrics_a, world), episode_records(metrics_b, world)
    return [{**b, **{BASELINE + name: value for name, value in a.items()}} for a, b in zip(records_a, records_b)]


class PairedObjective:
    """``evaluate(z[n, dim], seeds[n]) -> [Outcome]``: both agents on G(z) with the same keys; the
    score is metric(B) − metric(A), averaged over the world's episodes.

    Args:
        setup: the two agents and G; metric: canonical metric of the score.
        keep_worlds: store each world with its evaluation.
    """

    def __init__(self, setup: DiffSetup, metric: str, keep_worlds: bool = True):
        self.setup, self.metric, self.keep_worlds = setup, metric, keep_worlds

    def __call__(self, z: np.ndarray, seeds: np.ndarray) -> list[Outcome]:
        require_generator(self.setup)
        self.setup.generator.check_latents(np.asarray(z))
        return self.outcomes(generate(self.setup.generator, jnp.asarray(z, jnp.float32)), seeds)

    def outcomes(self, worlds: Any, seeds: np.ndarray) -> list[Outcome]:
        """Outcomes of ``worlds`` (batched, one per seed), each world played with its seed's keys by both agents."""
        setup, spec = self.setup, self.setup.spec
        keys = jnp.stack([jax.random.split(jax.random.key(int(seed)), setup.repeats) for seed in seeds])
        played = []
        for one in (setup.a, setup.b):
            metrics = evaluate(one.env, one.policy, worlds, setup.repeats, None, one.params, keys=keys)
            played.append(spec.metrics.with_derived(metrics, one.params))
        metrics_a, metrics_b = played
        scores = np.asarray(metrics_b[self.metric], np.float64).mean(axis=1) - np.asarray(metrics_a[self.metric], np.float64).mean(axis=1)
        return [
            Outcome(
                float(scores[i]),
                paired_episodes(metrics_a, metrics_b, i),
                jax.tree_util.tree_map(lambda leaf, i=i: np.asarray(leaf[i]), worlds) if self.keep_worlds else None,
            )
            for i in range(len(seeds))
        ]


class FixedWorlds:
    """``evaluate(indices f[n, 1], seeds[n]) -> [Outcome]``: ``PairedObjective.outcomes`` of given worlds, by index."""

    def __init__(self, objective: PairedObjective, worlds: Any):
        self.objective, self.worlds = objective, worlds

    def __call__(self, indices: np.ndarray, seeds: np.ndarray) -> list[Outcome]:
        picks = np.asarray(indices, np.int64).reshape(-1)
        return self.objective.outcomes(jax.tree_util.tree_map(lambda leaf: jnp.asarray(leaf)[picks], self.worlds), seeds)


# -- world sets -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class WorldSet:
    """Worlds to compare on.

    Attributes:
        worlds: the batched world pytree (leading axis W).
        latents: f64[W, dim] where G(z) made them, or None.
        source: what they are, as recorded (e.g. {"campaign": "random-return-s0", "store": ...}).
        tag: a short name for the campaign that compares on them.
    """

    worlds: Any
    latents: np.ndarray | None
    source: dict
    tag: str

    def __len__(self) -> int:
        return int(np.shape(jax.tree_util.tree_leaves(self.worlds)[0])[0])


def campaign_worlds(spec: EnvSpec, store_path: Path | str, name: str, generator: Any = None) -> WorldSet:
    """The worlds of stored campaign ``name`` (a ``store.sqlite`` or the run directory holding it); worlds
    not kept are decoded from their latents with ``generator``."""
    from worldagent.store import STORE_FILE

    path = Path(store_path)
    path = path / STORE_FILE if path.is_dir() else path
    if not path.is_file():
        raise WorldagentError(f"no run store at {path}; pass --store with a run directory or a store.sqlite a campaign wrote.")
    with RunStore(path, create=False) as store:
        campaign = store.campaign(name)
        if campaign is None:
            known = ", ".join(c.name for c in store.campaigns()) or "none"
            raise WorldagentError(f"no campaign {name!r} in {path}; campaigns there: {known}.")
        if campaign.env != spec.name:
            raise WorldagentError(f"campaign {name!r} holds {campaign.env} worlds, not {spec.name} worlds; pass a {spec.name} campaign.")
        found = store.evaluations(name, with_worlds=True)
    if not found:
        raise WorldagentError(f"campaign {name!r} in {path} has no evaluated worlds; pick one that ran.")
    latents = np.stack([e.latent for e in found]).astype(np.float64) if all(len(e.latent) for e in found) else None
    if all(e.world is not None for e in found):
        worlds = spec.stack_worlds([e.world for e in found])
    elif generator is not None and latents is not None:
        worlds = jax.tree_util.tree_map(np.asarray, generate(generator, jnp.asarray(latents, jnp.float32)))
    else:
        raise WorldagentError(f"campaign {name!r} kept no worlds; pass --generator to decode them from their latents.")
    return WorldSet(worlds, latents, {"campaign": name, "store": str(path)}, f"campaign-{name}")


def dataset_worlds(spec: EnvSpec, paths: list[Path | str]) -> WorldSet:
    """The worlds of dataset files (``worldagent dataset``, or one-world files the explorer saves), in order."""
    import hashlib

    from worldagent.worlds.dataset import WorldDataset

    if not paths:
        raise WorldagentError("no dataset files; pass --dataset FILE.npz (repeatable).")
    sets = [WorldDataset.load(path, spec.name) for path in paths]
    worlds = jax.tree_util.tree_map(lambda *leaves: np.concatenate([np.asarray(leaf) for leaf in leaves]), *(d.worlds for d in sets))
    digest = hashlib.sha256("".join(d.fingerprint for d in sets).encode()).hexdigest()[:10]
    return WorldSet(worlds, None, {"datasets": [str(p) for p in paths]}, f"dataset-{digest}")


def require_generator(setup: DiffSetup) -> None:
    """Worlds G(z) need a generator: refused in one line without one."""
    if setup.generator is None:
        raise WorldagentError("sampling or searching worlds G(z) needs a generator; pass --generator.")


def check_agents(store: RunStore, name: str, setup: DiffSetup) -> None:
    """A paired campaign already in the store must have compared the same two agents (``identity.agent_identity``:
    by content, a callable by its function too); else one line, before anything runs."""
    existing = store.campaign(name)
    if existing is None:
        return
    recorded = existing.config.get("diff", {})
    if [agent_identity(recorded.get(k, {})) for k in ("a", "b")] != [agent_identity(r) for r in setup.records().values()]:
        raise WorldagentError(f"campaign {name!r} in {store.path} compared other agents; pass another --out (or --seed) for these two.")


def set_campaign_name(tag: str, seed: int) -> str:
    """``diff-prior-s0``, ``diff-campaign-NAME-s0``, ``diff-dataset-HASH-s0``: a world set's paired campaign."""
    return f"diff-{tag}-s{seed}"


def search_campaign_name(search: str, maximize: bool, metric: str, seed: int) -> str:
    """``diff-cmaes-min-return-s0``: a differential search's campaign."""
    return f"diff-{search}-{'max' if maximize else 'min'}-{metric}-s{seed}"


def prior_set(store: RunStore, setup: DiffSetup, worlds: int, *, seed: int = 0, progress: bool = True) -> list[Evaluation]:
    """Both agents on ``worlds`` worlds G(z), z ~ N(0, I) (random search's stream for ``seed``): one
    paired campaign, resumed by a rerun. Returns its first ``worlds`` evaluations."""
    require_generator(setup)
    name = set_campaign_name("prior", seed)
    check_agents(store, name, setup)
    stored = store.evaluations(name)
    if len(stored) >= worlds:
        return stored[:worlds]
    main = setup.spec.metrics.main
    existing = store.campaign(name)
    config = OptimiserConfig(random_batch=existing.config["random_batch"] if existing else min(worlds, 250))  # a resumed campaign keeps its rounds
    spec = CampaignSpec(
        name, setup.spec.name, main, False, "random", int(worlds), int(seed), setup.generator.latent_dim, config,
        agent=agent_record(setup.b.policy), extra={"diff": setup.records()},
    )  # fmt: skip
    title = f"diff on {worlds} worlds G(z)"
    return run_campaign(store, spec, PairedObjective(setup, main), resume=True, progress=progress, backend=setup.backend, title=title)[:worlds]


def fixed_set(store: RunStore, setup: DiffSetup, world_set: WorldSet, *, seed: int = 0, progress: bool = True) -> list[Evaluation]:
    """Both agents on every world of ``world_set`` (world i as slot i of generation 0, its keys from
    ``stored_seed(campaign, 0, i)``): one paired campaign, committed batch by batch, resumed by a rerun."""
    main, count = setup.spec.metrics.main, len(world_set)
    name = set_campaign_name(world_set.tag, seed)
    check_agents(store, name, setup)
    dim = 0 if world_set.latents is None else world_set.latents.shape[1]
    config = {"dim": dim, "agent": agent_record(setup.b.policy), "diff": setup.records(), "worlds": world_set.source, "stream": campaign_stream(name)}
    campaign = store.open_campaign(name, setup.spec.name, main, False, "fixed", count, seed, config, resume=True)
    done = {e.slot for e in store.evaluations(name)}
    missing = [i for i in range(count) if i not in done]
    backend = setup.backend or LocalBackend()
    evaluate_batch = FixedWorlds(PairedObjective(setup, main), world_set.worlds)
    seeds = {s: stored_seed(campaign, 0, s) for s in missing}
    batches = [
        (slots, np.asarray(slots, np.float64)[:, None], np.array([seeds[s] for s in slots])) for slots in split(missing, backend.workers, SET_BATCH)
    ]
    with progress_bar(f"diff on {count} worlds", total=count, enabled=progress) as advance:
        advance(count - len(missing))
        for slots, outcomes in backend.run(evaluate_batch, batches):
            started = time.time()
            for slot, outcome in zip(slots, outcomes):
                latent = world_set.latents[slot] if world_set.latents is not None else np.zeros(0)
                store.add(campaign, 0, slot, latent, outcome.score, outcome.episodes, started, outcome.world)
            advance(len(slots))
    return store.evaluations(name)


def differential_search(
    store: RunStore,
    setup: DiffSetup,
    metric: str,
    *,
    search: str = "cmaes",
    maximize: bool = False,
    budget: int,
    seed: int = 0,
    descriptors: list[str] | None = None,
    cells: int = 10,
    progress: bool = True,
    prior_bound: float | str | None = TYPICAL,
) -> tuple[list[Evaluation], str]:
    """Search z for the worlds where metric(B) − metric(A) is lowest (``maximize``: highest): CMA-ES,
    or the atlas (CMA-ME over ``descriptors``, default the env's), with common random numbers; within the
    prior's typical set unless ``prior_bound`` says otherwise (``CampaignSpec.prior_bound``).

    Returns:
        (its evaluations in order, the campaign's name ``search_campaign_name``); a rerun resumes it.
    """
    from worldagent.search.atlas import atlas_optimiser

    if search not in SEARCHES:
        raise WorldagentError(f"unknown differential search {search!r}; use one of: {', '.join(SEARCHES)}.")
    require_generator(setup)
    metric = setup.spec.metrics.resolve(metric, setup.spec.name)
    name = search_campaign_name(search, maximize, metric, seed)
    check_agents(store, name, setup)
    extra, optimiser, kind = {"diff": setup.records()}, None, "cmaes"
    if search == "atlas":
        optimiser, grid = atlas_optimiser(setup.spec, setup.generator, maximize, seed, budget, descriptors, cells)
        extra, kind = {**extra, **grid}, "cma-me"
    spec = CampaignSpec(
        name, setup.spec.name, metric, maximize, kind, int(budget), int(seed), setup.generator.latent_dim,
        agent=agent_record(setup.b.policy), extra=extra, prior_bound=prior_bound,
    )  # fmt: skip
    objective = PairedObjective(setup, metric)
    title = f"{search} {'max' if maximize else 'min'}imising {metric}(B) − {metric}(A)"
    found = run_campaign(store, spec, objective, resume=True, progress=progress, backend=setup.backend, optimiser=optimiser, title=title)
    return found, name


# -- confirmation ---------------------------------------------------------------------------------


def confirm_worlds(
    store: RunStore,
    setup: DiffSetup,
    picks: list[Evaluation],
    selection: Any,
    metrics: list[str],
    *,
    name: str,
    repeats: int,
    seed: int,
    progress: bool = True,
) -> list[dict]:
    """Each picked paired evaluation confirmed for A and for B on the same ``repeats`` fresh episodes (A then B; stored,
    resumable, named ``name``), as ``analysis.paired.pair_row`` s."""
    from worldagent.analysis.confirm import confirm

    if repeats == 0 or not picks:
        return []
    a = confirm(store, side_setup(setup, "a"), [side_of(e, "a") for e in picks], name=f"{name}:A", repeats=repeats, seed=seed, progress=progress)
    b = confirm(store, side_setup(setup, "b"), [side_of(e, "b") for e in picks], name=f"{name}:B", repeats=repeats, seed=seed, progress=progress)
    return [pair_row(one, other, selection, metrics) for one, other in zip(a, b)]


def regressed_picks(store: RunStore, evaluations: list[Evaluation], spec: EnvSpec, selection: Any) -> tuple[list[Evaluation], int]:
    """(the first ``CONFIRMED_AT_MOST`` distinct regressed worlds, likeliest under the prior first; how many distinct there are)."""
    fail_a, fail_b, _, _ = failure_masks(evaluations, spec, selection)
    features, latents = features_of(evaluations, spec, store)
    order = regressed_order(evaluations, fail_a, fail_b, features, latents)
    firsts = distinct_firsts(order, world_digests([evaluations[i] for i in order], store))
    return [evaluations[i] for i in firsts[:CONFIRMED_AT_MOST]], len(firsts)


def confirmed_regressed(
    store: RunStore,
    setup: DiffSetup,
    evaluations: list[Evaluation],
    selection: Any,
    metrics: list[str],
    *,
    name: str,
    repeats: int,
    seed: int,
    progress: bool = True,
) -> dict | None:
    """The regressed worlds among ``evaluations`` (distinct, at most ``CONFIRMED_AT_MOST``) confirmed for both agents:
    ``analysis.paired.confirmed_pairs``; None when ``repeats`` is 0."""
    if repeats == 0:
        return None
    picks, found = regressed_picks(store, evaluations, setup.spec, selection)
    rows = confirm_worlds(store, setup, picks, selection, metrics, name=name, repeats=repeats, seed=seed, progress=progress)
    return confirmed_pairs(rows, found, repeats, selection)


def confirmed_search(
    store: RunStore, setup: DiffSetup, evaluations: list[Evaluation], search: dict, selection: Any, *, repeats: int, seed: int, progress: bool = True
) -> dict | None:
    """A differential search's reported worlds confirmed for both agents: its regressed worlds (``confirmed_regressed``:
    "regressed" is the confirmed count ``search_regressed`` gates read) and its most extreme world, whose confirmed
    drop (A − B of the searched metric over the shared fresh episodes; B − A when maximising) ``search_drop`` reads."""
    if repeats == 0:
        return None
    metric, name = search["metric"], f"diff:{search['campaign']}"
    metrics = list(dict.fromkeys((metric, *selection.metrics)))
    found = confirmed_regressed(store, setup, evaluations, selection, metrics, name=name, repeats=repeats, seed=seed, progress=progress)
    best = next(e for e in evaluations if (e.generation, e.slot) == (search["best"]["generation"], search["best"]["slot"]))
    row = confirm_worlds(store, setup, [best], selection, metrics, name=f"{name}:best", repeats=repeats, seed=seed, progress=progress)[0]
    change = row["difference"][metric]  # B − A
    sign = 1.0 if search["maximize"] else -1.0
    low, high = sorted((sign * change["low"], sign * change["high"]))
    found["best"] = row
    found["largest_drop"] = {"mean": sign * change["mean"], "low": low, "high": high, "episodes": change["episodes"]}
    found["episodes"] += 0 if row["world"] in {r["world"] for r in found["worlds"]} else 2 * repeats
    return found


# -- the whole comparison -------------------------------------------------------------------------


def world_noise(evaluations: list[Evaluation], metric: str, selection: Any) -> dict:
    """How much of each agent's ``metric`` (and of B's failure event) the world explains on a world set
    (``analysis.noise``: the share of one episode's variance between worlds), from its own episodes.

    Returns:
        {"repeats", "metric", "a", "b": ``WorldShare.as_dict()`` of A's and B's metric (None when not computed),
        "failure_b": that of B's failure event (None)}; {} with one episode per world (nothing to split).
    """
    from worldagent.analysis.noise import noise_summary

    b = noise_summary(evaluations, [metric], selection)
    if not b:
        return {}
    a = noise_summary(evaluations, [BASELINE + metric])
    return {
        "repeats": b["repeats"],
        "metric": metric,
        "a": a.get("metrics", {}).get(BASELINE + metric),
        "b": b["metrics"].get(metric),
        "failure_b": b.get("failure", {}).get("share"),
    }


def diff(
    store: RunStore,
    setup: DiffSetup,
    *,
    worlds: int | WorldSet | None = None,
    search: str | None = None,
    budget: int = 420,
    objective: str = "reward",
    maximize: bool = False,
    descriptors: list[str] | None = None,
    cells: int = 10,
    failure: str | None = None,
    metric: str = "reward",
    gate: Any = None,
    seed: int = 0,
    progress: bool = True,
    confirm: int = REPEATS,
    prior_bound: float | str | None = TYPICAL,
) -> dict:
    """Compare A and B on a world set and/or search for where B is worse; everything ``worldagent diff`` reports.

    Args:
        store: the run store (each world set and search is a campaign of it; a rerun resumes).
        setup: the two agents (``diff_setup``).
        worlds: a count of worlds G(z), z ~ N(0, I), a ``WorldSet``, or None (search only).
        search: "cmaes", "atlas" or None; ``budget`` its worlds, ``objective`` its metric,
            ``maximize`` its direction on metric(B) − metric(A), ``descriptors``/``cells`` the atlas's grid,
            ``prior_bound`` where it may go (default the prior's typical set).
        failure: which worlds fail (the event language; default the env's ``failure``).
        metric: the α-CVaR's metric (higher is better; default the main one).
        gate: an ``analysis.gate.Gate`` checked on the result (None: none).
        seed: seed of the worlds, the episodes, the search, the bootstrap and the confirmation keys.
        confirm: fresh episodes per reported world and agent (0 skips): the regressed worlds and the search's
            reported worlds replayed for A and B on the same keys (``confirmed_regressed``, ``confirmed_search``).

    Returns:
        {"env", "agents" {"a", "b"}, "seed", "repeats", "source", "worlds": ``summarise`` with "confirmed" and "noise"
        (``world_noise``) or None,
        "search": ``search_summary`` with "campaign", "confirmed", "prior_bound" (the radius searched within, None:
        beyond the prior) and the best world's "prior" (``search.prior.prior_summary``) or None, "episodes": all the comparison spent,
        "confirmation_episodes": those of the confirmations, "gate": its check or None}. The gate reads the paired
        statistics of the world set as they are (unbiased: every sampled world counts) and the search's confirmed figures.
    """
    from worldagent.analysis.gate import quantities
    from worldagent.events import parse_selection

    spec = setup.spec
    text = failure or spec.failure
    if not text:
        raise WorldagentError(f"{spec.name} names no failure event; pass --failure, e.g. '{spec.metrics.main} < 0'.")
    selection = parse_selection(text, spec.name)
    metric = spec.metrics.resolve(metric, spec.name)
    result = {"env": spec.name, "agents": setup.records(), "seed": seed, "repeats": setup.repeats, "source": None, "worlds": None, "search": None}
    if worlds is not None:
        if isinstance(worlds, WorldSet):
            found, result["source"] = fixed_set(store, setup, worlds, seed=seed, progress=progress), worlds.source
        else:
            found, result["source"] = prior_set(store, setup, int(worlds), seed=seed, progress=progress), {"prior": int(worlds)}
        result["worlds"] = {"campaign": found[0].campaign, **summarise(found, spec, selection, metric, store=store, seed=seed)}
        result["worlds"]["noise"] = world_noise(found, metric, selection)
        shown = list(dict.fromkeys((metric, *selection.metrics)))
        name = f"diff:{found[0].campaign}"
        result["worlds"]["confirmed"] = confirmed_regressed(
            store, setup, found, selection, shown, name=name, repeats=confirm, seed=seed, progress=progress
        )
    if search is not None:
        searched, name = differential_search(
            store,
            setup,
            objective,
            search=search,
            maximize=maximize,
            budget=budget,
            seed=seed,
            descriptors=descriptors,
            cells=cells,
            progress=progress,
            prior_bound=prior_bound,
        )
        result["search"] = {
            "campaign": name,
            "search": search,
            **search_summary(searched, spec, selection, spec.metrics.resolve(objective), maximize, store=store),
            "prior_bound": store.campaign(name).config.get("prior_bound"),
        }
        best = next(e for e in searched if (e.generation, e.slot) == (result["search"]["best"]["generation"], result["search"]["best"]["slot"]))
        result["search"]["best"]["prior"] = prior_summary(best.latent)
        result["search"]["confirmed"] = confirmed_search(
            store, setup, searched, result["search"], selection, repeats=confirm, seed=seed, progress=progress
        )
    result["episodes"] = sum(part["episodes"] for part in (result["worlds"], result["search"]) if part)
    result["confirmation_episodes"] = sum((part.get("confirmed") or {}).get("episodes", 0) for part in (result["worlds"], result["search"]) if part)
    result["gate"] = gate.check(quantities(result)) if gate is not None else None
    return result
