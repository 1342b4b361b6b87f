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


@dataclasses.dataclass(frozen=True)
class Jitted:
    """The env's functions jitted once per environment (compiling dominates these tests)."""

    reset: object
    step: object
    batch_reset: object
    batch_step: object
    rollout: object
    autoreset: object


@pytest.fixture(scope="module")
def jitted(case) -> Jitted:
    env = case.env
    policy = registry.ScriptedPolicy(None, lambda params, obs, key, state: case.random_action(key))
    return Jitted(
        reset=jax.jit(env.reset),
        step=jax.jit(env.step),
        batch_reset=jax.jit(jax.vmap(env.reset, in_axes=(0, 0, None))),
        batch_step=jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None))),
        rollout=jax.jit(lambda key, world, params: core.rollout(env, policy, key, world, params, STEPS)),
        autoreset=jax.jit(lambda key, state, action, params, next_world: core.step_autoreset(env, key, state, action, params, next_world)),
    )


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


def test_reset_and_step_under_jit_and_vmap_over_different_worlds(case, jitted):
    keys = jax.random.split(jax.random.key(0), (3, BATCH))
    obs, state = jitted.batch_reset(keys[0], case.worlds, case.params)
    assert obs.shape == (BATCH, *case.action_shape, *case.env.observation_shape)
    actions = jax.vmap(case.random_action)(keys[1])
    next_obs, next_state, reward, terminated, truncated, info = jitted.batch_step(keys[2], state, actions, case.params)
    assert next_obs.shape == obs.shape and next_obs.dtype == obs.dtype
    declared = getattr(case.env, "observation_dtype", None)
    if declared is not None:
        assert obs.dtype == jnp.dtype(declared)
    per_agent = (BATCH, *case.action_shape)
    assert reward.shape == per_agent and terminated.shape == per_agent and truncated.shape == per_agent
    assert terminated.dtype == jnp.bool_ and truncated.dtype == jnp.bool_
    assert isinstance(info, dict)
    # The batch is the worlds one by one (vmap walks over them) and they differ.
    one_obs, one_state = jitted.reset(keys[0, 1], case.world(1), case.params)
    np.testing.assert_allclose(np.asarray(obs[1]), np.asarray(one_obs), rtol=1e-6)
    one = jitted.step(keys[2, 1], one_state, actions[1], case.params)
    np.testing.assert_allclose(np.asarray(next_obs[1]), np.asarray(one[0]), rtol=1e-5, atol=1e-6)
    assert any(not np.array_equal(np.asarray(obs[0]), np.asarray(obs[i])) for i in range(1, BATCH))


def test_same_key_same_episode(case, jitted):
    first = jitted.rollout(jax.random.key(7), case.world(0), case.params)
    again = jitted.rollout(jax.random.key(7), case.world(0), case.params)
    assert_trees_equal(first, again)
    assert_trees_equal(case.env.metrics(first[0]), case.env.metrics(again[0]))


def test_truncated_exactly_at_the_step_limit_unless_terminated(case):
    def run(key, world):
        obs, state = case.env.reset(key, world, case.params)

        def one(state, key):
            _, state, _, terminated, truncated, _ = case.env.step(key, state, case.random_action(key), case.params)
            return state, (jnp.any(terminated), jnp.any(truncated))

        return jax.lax.scan(one, state, jax.random.split(key, STEPS))[1]

    terminated, truncated = jax.jit(jax.vmap(run))(jax.random.split(jax.random.key(3), BATCH), case.worlds)
    terminated, truncated = np.asarray(terminated), np.asarray(truncated)  # [BATCH, STEPS]
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
    autoreset = jitted.autoreset
    obs, state = jitted.reset(jax.random.key(0), world, case.params)
    action = case.random_action(jax.random.key(1))
    key = jax.random.key(2)
    # A limit of one step ends the episode at once: the new episode starts on next_world.
    ended = short(case.params, 1)
    new_obs, new_state, *_ = autoreset(key, state, action, ended, next_world)
    fresh_obs, fresh_state = jitted.reset(jax.random.split(key)[1], next_world, ended)
    np.testing.assert_allclose(np.asarray(new_obs), np.asarray(fresh_obs), rtol=1e-6)
    assert_trees_equal(new_state.world, fresh_state.world)
    assert_trees_equal(new_state.replace(world=None), fresh_state.replace(world=None))
    # An episode that goes on stays on its world (the next world is ignored).
    long = short(case.params, 100)
    going_obs, going_state, _, terminated, truncated, _ = autoreset(key, state, action, long, next_world)
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


def test_metrics_are_declared(case, jitted):
    declared = case.spec.metrics
    assert declared.resolve("reward") == declared.main and declared.main in declared.names
    _, state = jitted.reset(jax.random.key(0), case.world(0), case.params)
    final, _ = jitted.rollout(jax.random.key(1), case.world(0), case.params)
    for metrics in (case.env.metrics(state), case.env.metrics(final)):
        # Per-agent breakdowns (harvest's "returns" f32[N]) feed pictures, not searches: allowed undeclared.
        per_agent = {name for name, value in metrics.items() if case.action_shape and np.shape(value) == case.action_shape}
        assert set(metrics) - per_agent <= set(declared.names)
        derived = declared.with_derived({name: np.asarray(value)[None] for name, value in metrics.items()}, case.params)
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


def test_declared_algorithms_pictures_and_presets(case):
    from worldagent.agents.algorithms import ALGORITHMS

    assert case.spec.default_algorithm in ALGORITHMS and set(case.spec.algorithms) <= set(ALGORITHMS)
    image = case.spec.pictures.world(case.world(0), 48)
    assert image.size == (48, 48)
    assert all(isinstance(budgets, dict) or hasattr(budgets, "keys") for budgets in case.spec.presets.values())
    if case.spec.selection:
        from worldagent.influence.selection import parse_selection

        parse_selection(case.spec.selection, case.spec.name)
