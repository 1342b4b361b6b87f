"""Conformance of every registered environment to the env contract (issue 11, item 6).

Parametrised over ``registry.names()`` at collection, plus the toy environment of
``tests/toy_env`` (registered for this module only), so an environment registered by a new
folder or an installed plugin is covered without editing this file. Each test is small: a batch
of four worlds, a step limit of ``STEPS``.
"""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import toy_env
from worldagent.envs import core, registry
from worldagent.errors import WorldagentError

STEPS = 6  # the step limit every test sets (params.max_steps)
BATCH = 4  # worlds per batch
NAMES = tuple(dict.fromkeys((*registry.names(), toy_env.NAME)))


@pytest.fixture(scope="module", autouse=True)
def _toy_registered():
    with toy_env.registered():
        yield


@dataclasses.dataclass(frozen=True)
class Case:
    """One environment under test, with jitted functions compiled once per module."""

    spec: registry.EnvSpec
    env: core.Environment
    params: object
    worlds: object

    @property
    def action_shape(self) -> tuple[int, ...]:
        """``()``, or ``(N,)`` for N agents: multi-agent envs put a leading agent axis on actions, rewards, obs."""
        return () if self.env.num_agents == 1 else (self.env.num_agents,)

    def world(self, index: int):
        return jax.tree_util.tree_map(lambda leaf: leaf[index], self.worlds)

    def random_action(self, key):
        return jax.random.randint(key, self.action_shape, 0, self.env.num_actions)


def short(params, steps: int):
    """``params`` with ``max_steps`` set to ``steps``, keeping its type (python int or array)."""
    old = params.max_steps
    return params.replace(max_steps=jnp.asarray(steps, jnp.asarray(old).dtype) if isinstance(old, jax.Array) else steps)


@pytest.fixture(scope="module", params=NAMES)
def case(request) -> Case:
    spec = registry.get(request.param)
    env, params = spec.make_env()
    return Case(spec, env, short(params, STEPS), spec.generate(np.arange(BATCH)))


def episode(env, random_action, key, world, params):
    """A random-action episode of ``STEPS`` steps (not frozen at its end: only the first end is checked).

    The keys: ``key -> (steps, reset)``; step t: ``steps[t] -> (act, env)``.
    """
    key_steps, key_reset = jax.random.split(key)
    obs, state = env.reset(key_reset, world, params)

    def one(state, key):
        key_act, key_env = jax.random.split(key)
        action = random_action(key_act)
        obs, state, reward, terminated, truncated, _ = env.step(key_env, state, action, params)
        return state, {"obs": obs, "action": action, "reward": reward, "terminated": terminated, "truncated": truncated}

    final, steps = jax.lax.scan(one, state, jax.random.split(key_steps, STEPS))
    return {"obs0": obs, "final": final, **steps}


@dataclasses.dataclass(frozen=True)
class Jitted:
    """The env's functions jitted once per environment (compiling dominates these tests).

    Attributes:
        episodes: ``(keys[B], worlds[B], params) -> episode`` under jit and vmap.
        reset, step: one world, jitted.
        autoreset: ``core.step_autoreset`` with a ``next_world``, jitted.
    """

    episodes: object
    reset: object
    step: object
    autoreset: object


@pytest.fixture(scope="module")
def jitted(case) -> Jitted:
    env = case.env
    return Jitted(
        episodes=jax.jit(jax.vmap(lambda key, world, params: episode(env, case.random_action, key, world, params), in_axes=(0, 0, None))),
        reset=jax.jit(env.reset),
        step=jax.jit(env.step),
        autoreset=jax.jit(lambda key, state, action, params, next_world: core.step_autoreset(env, key, state, action, params, next_world)),
    )


@pytest.fixture(scope="module")
def played(case, jitted) -> dict:
    """``BATCH`` random episodes, one per world, as numpy (keys: ``KEYS``)."""
    return jax.tree_util.tree_map(np.asarray, jitted.episodes(KEYS, case.worlds, case.params))


KEYS = jax.random.split(jax.random.key(0), BATCH)


def assert_trees_equal(a, b):
    assert jax.tree_util.tree_structure(a) == jax.tree_util.tree_structure(b)
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_generator_is_deterministic_and_its_worlds_are_accepted(case):
    again = case.spec.generate(np.arange(BATCH))
    assert_trees_equal(case.worlds, again)
    assert isinstance(case.worlds, case.spec.world_type)
    for index in range(BATCH):
        case.env.check_world(case.world(index))
    cells = case.spec.cells(case.worlds)
    assert len({bytes(row) for row in np.asarray(cells)}) > 1, "different seeds should give different worlds"


def test_reset_and_step_under_jit_and_vmap_over_different_worlds(case, jitted, played):
    agents = case.action_shape
    assert played["obs0"].shape == (BATCH, *agents, *case.env.observation_shape)
    assert played["obs"].shape == (BATCH, STEPS, *agents, *case.env.observation_shape)
    assert played["obs"].dtype == played["obs0"].dtype
    declared = getattr(case.env, "observation_dtype", None)
    if declared is not None:
        assert played["obs0"].dtype == jnp.dtype(declared)
    for name in ("reward", "terminated", "truncated"):
        assert played[name].shape == (BATCH, STEPS, *agents), name
    assert played["terminated"].dtype == np.bool_ and played["truncated"].dtype == np.bool_
    assert any(not np.array_equal(played["obs0"][0], played["obs0"][i]) for i in range(1, BATCH)), "the worlds differ"
    # vmap walks over the worlds: world 1 played alone, unbatched, is the batch's row 1.
    key_steps, key_reset = jax.random.split(KEYS[1])
    obs, state = jitted.reset(key_reset, case.world(1), case.params)
    key_act, key_env = jax.random.split(jax.random.split(key_steps, STEPS)[0])
    step_obs, _, reward, *_ = jitted.step(key_env, state, case.random_action(key_act), case.params)
    np.testing.assert_allclose(np.asarray(obs), played["obs0"][1], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(step_obs), played["obs"][1, 0], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(reward), played["reward"][1, 0], rtol=1e-5, atol=1e-6)


def test_same_key_same_episode(case, jitted, played):
    again = jax.tree_util.tree_map(np.asarray, jitted.episodes(KEYS, case.worlds, case.params))
    assert_trees_equal(played, again)
    other = jax.tree_util.tree_map(np.asarray, jitted.episodes(jax.random.split(jax.random.key(1), BATCH), case.worlds, case.params))
    assert not np.array_equal(played["action"], other["action"]), "another key, another episode"


def test_truncated_exactly_at_the_step_limit_unless_terminated(played):
    terminated, truncated = played["terminated"], played["truncated"]
    if terminated.ndim > 2:  # multi-agent: an episode ends for everybody at once
        terminated, truncated = terminated.any(axis=-1), truncated.any(axis=-1)
    truncations = 0
    for ends, cuts in zip(terminated, truncated):
        first_end = int(np.argmax(ends | cuts)) if (ends | cuts).any() else STEPS
        assert first_end < STEPS, "an episode must end by params.max_steps"
        assert not (ends[first_end] and cuts[first_end]), "terminated and truncated are exclusive"
        assert not cuts[:first_end].any()
        if cuts[first_end]:
            assert first_end == STEPS - 1, f"truncated at step {first_end + 1}, not at the limit {STEPS}"
            truncations += 1
    assert truncations, "no episode ran to the step limit; the test did not exercise truncation"


def test_autoreset_onto_next_world(case, jitted):
    world, next_world = case.world(0), case.world(1)
    obs, state = jitted.reset(jax.random.key(0), world, case.params)
    action = case.random_action(jax.random.key(1))
    key = jax.random.key(2)
    # A limit of one step ends the episode at once: the new episode starts on next_world.
    ended = short(case.params, 1)
    new_obs, new_state, *_ = jitted.autoreset(key, state, action, ended, next_world)
    fresh_obs, fresh_state = jitted.reset(jax.random.split(key)[1], next_world, ended)
    np.testing.assert_allclose(np.asarray(new_obs), np.asarray(fresh_obs), rtol=1e-6)
    assert_trees_equal(new_state.world, fresh_state.world)
    assert_trees_equal(new_state.replace(world=None), fresh_state.replace(world=None))
    # An episode that goes on stays on its world (the next world is ignored).
    long = short(case.params, 100)
    going_obs, going_state, _, terminated, truncated, _ = jitted.autoreset(key, state, action, long, next_world)
    if not np.any(terminated) and not np.any(truncated):
        assert_trees_equal(going_state.world, state.world)
        stepped_obs = jitted.step(jax.random.split(key)[0], state, action, long)[0]
        np.testing.assert_allclose(np.asarray(going_obs), np.asarray(stepped_obs), rtol=1e-5, atol=1e-6)


def test_world_store_arrays_round_trip(case):
    arrays = case.spec.world_to_arrays(case.worlds)
    assert all(isinstance(value, np.ndarray) for value in arrays.values())
    assert_trees_equal(case.spec.world_from_arrays(arrays), case.worlds)
    single = [case.spec.world_to_arrays(case.world(i)) for i in range(BATCH)]
    assert_trees_equal(case.spec.stack_worlds(single), case.worlds)
    with pytest.raises(WorldagentError):
        case.spec.world_from_arrays({**arrays, "unexpected": np.zeros(1)})


def damaged(world):
    """``world`` with its first field cut by one along its last axis (the others intact)."""
    first = dataclasses.fields(world)[0].name
    return world.replace(**{first: np.asarray(getattr(world, first))[..., :-1]})


def assert_one_line_refusal(call):
    with pytest.raises(WorldagentError) as error:
        call()
    message = str(error.value)
    assert message and "\n" not in message


def test_malformed_world_is_refused_with_a_one_line_error(case):
    broken = damaged(case.world(0))
    assert_one_line_refusal(lambda: case.env.check_world(broken))
    assert_one_line_refusal(broken.validate)
    assert_one_line_refusal(lambda: case.env.check_world({"not": "a world"}))


def test_cells_are_binary_with_the_declared_shape(case):
    cells = np.asarray(case.spec.cells(case.worlds))
    assert cells.shape == (BATCH, int(np.prod(case.spec.cell_shape))) and cells.shape[1] == case.spec.cell_count
    assert cells.dtype == np.uint8 and np.isin(cells, (0, 1)).all()


def test_metrics_are_declared(case, jitted, played):
    declared = case.spec.metrics
    assert declared.resolve("reward") == declared.main and declared.main in declared.names
    _, state = jitted.reset(jax.random.key(0), case.world(0), case.params)
    final = jax.tree_util.tree_map(lambda leaf: leaf[0], played["final"])
    for metrics in (case.env.metrics(state), case.env.metrics(final)):
        # Per-agent breakdowns (harvest's "returns" f32[N]) feed pictures, not searches: allowed undeclared.
        per_agent = {name for name, value in metrics.items() if case.action_shape and np.shape(value) == case.action_shape}
        assert set(metrics) - per_agent <= set(declared.names)
        derived = declared.with_derived({name: np.asarray(value)[None] for name, value in metrics.items()}, case.params)
        assert all(np.all(np.isfinite(np.asarray(value, np.float64))) for value in derived.values())
        assert set(derived) - per_agent <= set(declared.names)
    assert {declared.resolve(alias) for alias in declared.aliases} <= set(declared.names)
    assert set(declared.compared) | set(declared.highlighted) <= set(declared.names)
    assert set(declared.default_descriptors) <= set(declared.descriptors)
    for describe in declared.descriptors.values():
        assert np.isfinite(float(describe(case.world(0))))
    assert np.all(np.isfinite(declared.normalise([0.0], case.params, best_episode=1.0)))


def test_scripted_policies_act_with_the_right_action_shape(case, jitted):
    obs, state = jitted.reset(jax.random.key(0), case.world(0), case.params)
    for name, factory in case.spec.scripted.items():
        policy = factory(case.env, case.params)
        action = jax.jit(policy.act)(policy.params, obs, jax.random.key(1), state)
        assert action.shape == case.action_shape, name
        assert jnp.issubdtype(action.dtype, jnp.integer) and np.all((0 <= action) & (action < case.env.num_actions)), name
        jitted.step(jax.random.key(2), state, action, case.params)


def test_repair_makes_dataset_cells_valid_worlds(case):
    from worldagent.worlds.dataset import make_dataset

    dataset = make_dataset(case.spec.name, 8, 0, progress=False)
    repair = case.spec.repair(dataset, None)
    config = json.loads(json.dumps(repair.config))
    logits = jnp.asarray(dataset.cells, jnp.float32) * 20.0 - 10.0  # confident decodings of the worlds' own cells
    repaired = jax.jit(lambda repair, logits: repair(logits))(repair, logits)
    for index in range(len(dataset)):
        case.env.check_world(jax.tree_util.tree_map(lambda leaf: np.asarray(leaf[index]), repaired))
    assert_trees_equal(case.spec.repair(dataset, config)(logits), repaired)
    from worldagent.worlds.generator import make_repair

    with pytest.raises(WorldagentError):  # an unknown setting (generator train --repair) is refused, not ignored
        make_repair(dataset, {"no_such_setting": 1})


def test_declared_algorithms_pictures_and_presets(case):
    from worldagent.agents.algorithms import ALGORITHMS

    assert case.spec.default_algorithm in ALGORITHMS and set(case.spec.algorithms) <= set(ALGORITHMS)
    image = case.spec.pictures.world(case.world(0), 48)
    assert image.size == (48, 48)
    assert all(isinstance(budgets, dict) or hasattr(budgets, "keys") for budgets in case.spec.presets.values())
    if case.spec.selection:
        from worldagent.events import parse_selection

        parse_selection(case.spec.selection, case.spec.name)


def test_actor_critic_algorithms_get_a_flat_observation(case):
    """PPO and ACKTR's network reads a flat observation f32[D] (``agents.networks`` refuses others)."""
    from worldagent.agents.networks import check_flat_observation

    if {"ppo", "acktr"} & set(case.spec.algorithms):
        check_flat_observation(case.env.observation_shape)


DESCRIBED = 64  # generated worlds each descriptor is measured on


def test_descriptors_vary_over_generated_worlds(case):
    """``worldagent atlas`` refuses a descriptor constant over its 512 G(z) samples; one constant
    over the procedural generator's worlds would be."""
    worlds = case.spec.generate(np.arange(DESCRIBED))
    for name, describe in case.spec.metrics.descriptors.items():
        values = {float(describe(jax.tree_util.tree_map(lambda leaf, i=i: np.asarray(leaf)[i], worlds))) for i in range(DESCRIBED)}
        assert len(values) > 1, f"descriptor {name!r} is the same on {DESCRIBED} generated worlds; the atlas would refuse it"


def test_episode_pictures_draw_episodes(case, jitted, played):
    """``pictures.episodes(axis, world, episodes)`` draws an ``evaluation.trajectories.Episodes``
    (what ``play`` and the reports replay): here one episode traced at its start and its end, as
    ``spec.trace`` says where the agents are; ``episode_note`` reads its metrics."""
    from worldagent.evaluation.trajectories import Episodes
    from worldagent.reports.figures import _pyplot

    if case.spec.pictures.episodes is None:
        pytest.skip(f"{case.spec.name} registers no episode picture")
    _, start = jitted.reset(KEYS[0], case.world(0), case.params)
    final = jax.tree_util.tree_map(lambda leaf: leaf[0], played["final"])
    (first, first_present), (last, last_present) = case.spec.trace(start), case.spec.trace(final)
    metrics = {name: np.asarray(value)[None] for name, value in case.env.metrics(final).items()}
    episodes = Episodes(
        positions=np.stack([first, last])[None], present=np.stack([first_present, last_present])[None], steps=np.array([1]), metrics=metrics
    )
    plt = _pyplot()
    figure, axis = plt.subplots()
    try:
        case.spec.pictures.episodes(axis, case.world(0), episodes)
    finally:
        plt.close(figure)
    if case.spec.episode_note:
        assert isinstance(case.spec.episode_note(episodes.metrics), str)


def test_failure_and_training_check_are_usable(case, jitted, played):
    """``failure`` parses as a selection; ``training_check`` reads mean metrics and returns text."""
    from worldagent.events import parse_selection

    if case.spec.failure:
        parse_selection(case.spec.failure, case.spec.name)
    if case.spec.training_check is not None:
        final = case.spec.metrics.with_derived(jax.tree_util.tree_map(np.asarray, jax.vmap(case.env.metrics)(played["final"])), case.params)
        means = {name: float(np.mean(value)) for name, value in final.items()}
        assert isinstance(case.spec.training_check(means), str)
