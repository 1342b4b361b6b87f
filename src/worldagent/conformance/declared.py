"""Conformance checks of what an ``EnvSpec`` declares (metrics, policies, repair, algorithms, pictures, events, world
sets): each runs once per environment, on its generated worlds (see ``conformance.checks`` for the contract)."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.conformance.checks import CheckFailed, Skipped, check, require, trees_equal
from worldagent.conformance.subject import Subject, take
from worldagent.errors import WorldagentError


@check("metrics are declared and finite")
def metrics_declared(subject: Subject) -> str:
    declared = subject.spec.metrics
    require(declared.resolve("reward") == declared.main and declared.main in declared.names, f"the main metric {declared.main!r} is not in names")
    _, state = subject.jitted.reset(jax.random.key(0), subject.world(0), subject.params)
    for when, metrics in (
        ("after reset", subject.env.metrics(state)),
        ("at an episode's end", subject.env.metrics(take(subject.played["final"], 0))),
    ):
        # Per-agent breakdowns (harvest's "returns" f32[N]) feed pictures, not searches: allowed undeclared.
        per_agent = {name for name, value in metrics.items() if subject.action_shape and np.shape(value) == subject.action_shape}
        undeclared = sorted(set(metrics) - per_agent - set(declared.names))
        require(not undeclared, f"env.metrics {when} gives {undeclared}, not in spec.metrics.names")
        derived = declared.with_derived({name: np.asarray(value)[None] for name, value in metrics.items()}, subject.params)
        broken = sorted(name for name, value in derived.items() if not np.all(np.isfinite(np.asarray(value, np.float64))))
        require(not broken, f"metrics {broken} are not finite {when}")
        undeclared = sorted(set(derived) - per_agent - set(declared.names))
        require(not undeclared, f"derived metrics {undeclared} are not in spec.metrics.names")
    require({declared.resolve(alias) for alias in declared.aliases} <= set(declared.names), "an alias names no declared metric")
    require(set(declared.compared) | set(declared.highlighted) <= set(declared.names), "compared or highlighted names an undeclared metric")
    require(set(declared.default_descriptors) <= set(declared.descriptors), "default_descriptors names an undeclared descriptor")
    for name, describe in declared.descriptors.items():
        require(np.isfinite(float(describe(subject.world(0)))), f"descriptor {name!r} is not finite on world 0")
    require(np.all(np.isfinite(declared.normalise([0.0], subject.params, best_episode=1.0))), "normalise gives a non-finite value")
    return f"{len(declared.names)} metrics (main {declared.main}), aliases, compared, descriptors consistent"


@check("scripted policies act in range")
def scripted_policies(subject: Subject) -> str:
    spec, env = subject.spec, subject.env
    if not spec.scripted:
        raise Skipped("no scripted policies")
    obs, state = subject.jitted.reset(jax.random.key(0), subject.world(0), subject.params)
    for name, factory in spec.scripted.items():
        policy = factory(env, subject.params)
        action = jax.jit(policy.act)(policy.params, obs, jax.random.key(1), state)
        require(action.shape == subject.action_shape, f"{name} returns actions of shape {action.shape}, not {subject.action_shape}")
        require(jnp.issubdtype(action.dtype, jnp.integer), f"{name} returns {action.dtype} actions, not integers")
        require(np.all((0 <= action) & (action < env.num_actions)), f"{name} acts outside 0..{env.num_actions - 1}")
        subject.jitted.step(jax.random.key(2), state, action, subject.params)
    return f"{', '.join(spec.scripted)}: integer actions of shape {subject.action_shape or '()'} in range"


@check("the repair makes dataset cells valid worlds")
def repair_valid(subject: Subject) -> str:
    from worldagent.worlds.dataset import make_dataset
    from worldagent.worlds.generator import make_repair

    spec = subject.spec
    dataset = make_dataset(spec.name, 8, 0, progress=False)
    repair = spec.repair(dataset, None)
    config = json.loads(json.dumps(repair.config))
    logits = jnp.asarray(dataset.cells, jnp.float32) * 20.0 - 10.0  # confident decodings of the worlds' own cells
    repaired = jax.jit(lambda repair, logits: repair(logits))(repair, logits)
    for index in range(len(dataset)):
        try:
            subject.env.check_world(take(repaired, index))
        except WorldagentError as error:
            raise CheckFailed(f"the repair of dataset world {index}'s own cells is refused: {error}") from None
    require(trees_equal(spec.repair(dataset, config)(logits), repaired), "the repair rebuilt from its JSON config repairs otherwise")
    try:
        make_repair(dataset, {"no_such_setting": 1})
    except WorldagentError:
        pass
    else:
        raise CheckFailed("the repair accepted an unknown setting (generator train --repair); refuse unknown names")
    return f"{len(dataset)} worlds' own cells repaired to valid worlds under jit; rebuilt from JSON; unknown settings refused"


@check("algorithms, optimiser, pictures and presets are usable")
def declared_usable(subject: Subject) -> str:
    from worldagent.agents.algorithms import ALGORITHMS
    from worldagent.search.optimisers import OPTIMISERS

    spec = subject.spec
    unknown = sorted(set(spec.algorithms) - set(ALGORITHMS))
    require(spec.algorithms and not unknown, f"algorithms {list(spec.algorithms)}: use some of {', '.join(ALGORITHMS)}")
    require(spec.optimiser in OPTIMISERS, f"optimiser {spec.optimiser!r}: use one of {', '.join(OPTIMISERS)}")
    size = spec.pictures.world(subject.world(0), 48).size
    require(size == (48, 48), f"pictures.world(world, 48) draws {size}, not (48, 48)")
    require(all(hasattr(budgets, "keys") for budgets in spec.presets.values()), "every preset must be a mapping of budgets")
    if spec.selection:
        from worldagent.events import parse_selection

        parse_selection(spec.selection, spec.name)
    return f"algorithms {', '.join(spec.algorithms)}; optimiser {spec.optimiser}; a 48 px picture; {len(spec.presets)} preset(s)" + (
        f"; selection {spec.selection!r}" if spec.selection else ""
    )


@check("actor-critics get a flat observation")
def flat_observation(subject: Subject) -> str:
    """PPO and ACKTR's network reads a flat observation f32[D] (``agents.networks`` refuses others)."""
    from worldagent.agents.networks import check_flat_observation

    if not {"ppo", "acktr"} & set(subject.spec.algorithms):
        raise Skipped("trains with neither PPO nor ACKTR")
    check_flat_observation(subject.env.observation_shape)
    return f"observation shape {tuple(subject.env.observation_shape)}"


@check("failure event and training check are usable")
def failure_usable(subject: Subject) -> str:
    """``failure`` parses as a selection; ``training_check`` reads mean metrics and returns text."""
    from worldagent.events import parse_selection

    spec = subject.spec
    if not spec.failure and spec.training_check is None:
        raise Skipped("declares neither a failure event nor a training check")
    if spec.failure:
        parse_selection(spec.failure, spec.name)
    if spec.training_check is not None:
        final = spec.metrics.with_derived(jax.tree_util.tree_map(np.asarray, jax.vmap(subject.env.metrics)(subject.played["final"])), subject.params)
        verdict = spec.training_check({name: float(np.mean(value)) for name, value in final.items()})
        require(isinstance(verdict, str), f"training_check returned a {type(verdict).__name__}, not text")
    return ", ".join(
        part for part in (spec.failure and f"failure {spec.failure!r} parses", spec.training_check and "training_check returns text") if part
    )


@check("named world sets are valid worlds")
def world_sets_valid(subject: Subject) -> str:
    """Each of ``spec.world_sets`` builds a batch of ``world_type`` whose worlds pass ``check_world`` and round-trip the store."""
    spec = subject.spec
    if not spec.world_sets:
        raise Skipped("declares no named world sets")
    sizes = []
    for name, build in spec.world_sets.items():
        worlds = build()
        require(isinstance(worlds, spec.world_type), f"world set {name!r} gives a {type(worlds).__name__}, not a batched {spec.world_type.__name__}")
        count = len(jax.tree_util.tree_leaves(worlds)[0])
        require(count >= 1, f"world set {name!r} is empty")
        for index in range(count):
            try:
                subject.env.check_world(take(worlds, index))
            except WorldagentError as error:
                raise CheckFailed(f"world {index} of set {name!r} is refused: {error}") from None
        require(
            trees_equal(spec.world_from_arrays(spec.world_to_arrays(worlds)), take(worlds, slice(None))),
            f"world set {name!r} does not round-trip the store",
        )
        sizes.append(f"{name} ({count})")
    return f"{', '.join(sizes)}: every world accepted by check_world"
