"""The conformance checks, one function each: ``check(subject) -> Result`` (pass, fail or skip, with a one-line reason).

Each check is a plain function (pytest is no runtime dependency): its body raises ``CheckFailed`` through
``require`` when the contract is broken, ``Skipped`` when it does not apply, and returns what it verified;
the ``check`` decorator turns that, or any other exception, into a ``Result``. ``tests/envs/test_conformance.py``
calls these same functions, so each check lives in one place.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.conformance.subject import BATCH, DECODED, STEPS, Subject, short, take
from worldagent.errors import WorldagentError

PASS, FAIL, SKIP = "pass", "FAIL", "skip"


class CheckFailed(Exception):
    """The contract is broken; the message says how, in one line."""


class Skipped(Exception):
    """The check does not apply to this environment; the message says why."""


@dataclasses.dataclass(frozen=True)
class Result:
    """One check's outcome.

    Attributes:
        name: the check, in a few words.
        status: ``PASS``, ``FAIL`` or ``SKIP``.
        reason: one line: what was verified, what broke, or why it does not apply.
        error: the exception behind a failure (its traceback, for tests), or None.
    """

    name: str
    status: str
    reason: str
    error: BaseException | None = dataclasses.field(default=None, repr=False, compare=False)

    @property
    def passed(self) -> bool:
        """True unless it failed (a skipped check passes)."""
        return self.status != FAIL


def one_line(text: object) -> str:
    return " ".join(str(text).split())


def require(condition: Any, reason: str) -> None:
    """Fail the running check with ``reason`` unless ``condition`` holds."""
    if not condition:
        raise CheckFailed(reason)


def check(name: str) -> Callable[[Callable[[Subject], str]], Callable[[Subject], Result]]:
    """Decorator: ``body(subject) -> what it verified`` becomes ``check(subject) -> Result`` named ``name``."""

    def wrap(body: Callable[[Subject], str]) -> Callable[[Subject], Result]:
        @functools.wraps(body)
        def run(subject: Subject) -> Result:
            try:
                return Result(name, PASS, one_line(body(subject)))
            except Skipped as why:
                return Result(name, SKIP, one_line(why))
            except CheckFailed as why:
                return Result(name, FAIL, one_line(why), why)
            except Exception as error:  # noqa: BLE001 - a crash is a failed check, reported in one line
                return Result(name, FAIL, one_line(f"{type(error).__name__}: {error}")[:300], error)

        run.check_name = name
        return run

    return wrap


def trees_equal(a: Any, b: Any) -> bool:
    """Same structure and the same values, leaf by leaf."""
    if jax.tree_util.tree_structure(a) != jax.tree_util.tree_structure(b):
        return False
    return all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)))


def refuses_in_one_line(call: Callable[[], Any]) -> str | None:
    """None when ``call`` raises a one-line ``WorldagentError``, else what it did instead."""
    try:
        call()
    except WorldagentError as error:
        return None if str(error) and "\n" not in str(error) else f"its error is not one line: {str(error)[:80]!r}"
    except Exception as error:  # noqa: BLE001 - what it raised instead is the finding
        return f"it raised {type(error).__name__}, not a WorldagentError"
    return "it was accepted"


# -- worlds --------------------------------------------------------------------------------------


@check("generator is deterministic, its worlds accepted")
def generator_deterministic(subject: Subject) -> str:
    """``generate`` gives the same worlds for the same seeds, of ``world_type``, passing ``check_world``; seeds differ."""
    spec = subject.spec
    require(
        trees_equal(subject.worlds, spec.generate(np.arange(BATCH))),
        "generate(seeds) gave other worlds the second time; make it depend on the seeds only",
    )
    require(isinstance(subject.worlds, spec.world_type), f"generate returned a {type(subject.worlds).__name__}, not a {spec.world_type.__name__}")
    for index in range(BATCH):
        subject.env.check_world(subject.world(index))
    require(len({bytes(row) for row in np.asarray(spec.cells(subject.worlds))}) > 1, "seeds 0-3 gave the same world; different seeds should differ")
    return f"seeds 0-{BATCH - 1}: the same worlds twice, all accepted by check_world, not all alike"


@check("decoded worlds are valid")
def decoded_valid(subject: Subject) -> str:
    """Every world G(z) made is of ``world_type`` and passes ``check_world`` (the repair's promise)."""
    spec, worlds = subject.spec, subject.described
    require(isinstance(worlds, spec.world_type), f"G(z) returned a {type(worlds).__name__}, not a {spec.world_type.__name__}")
    count = len(jax.tree_util.tree_leaves(worlds)[0])
    for index in range(count):
        try:
            subject.env.check_world(take(worlds, index))
        except WorldagentError as error:
            raise CheckFailed(f"decoded world {index} is refused: {error}") from None
    return f"{count} worlds, {subject.source}, all accepted by check_world"


@check("reset and step under jit and vmap")
def reset_and_step(subject: Subject) -> str:
    """Shapes and dtypes of a batch of episodes over different worlds; world 1 alone is the batch's row 1."""
    played, env, agents = subject.played, subject.env, subject.action_shape
    require(
        played["obs0"].shape == (BATCH, *agents, *env.observation_shape),
        f"reset's observations have shape {played['obs0'].shape[1:]}, not {(*agents, *env.observation_shape)}",
    )
    require(played["obs"].shape == (BATCH, STEPS, *agents, *env.observation_shape), f"step's observations have shape {played['obs'].shape[2:]}")
    require(played["obs"].dtype == played["obs0"].dtype, f"reset observes {played['obs0'].dtype}, step {played['obs'].dtype}; use one dtype")
    declared = getattr(env, "observation_dtype", None)
    require(declared is None or played["obs0"].dtype == jnp.dtype(declared), f"observations are {played['obs0'].dtype}, not the declared {declared}")
    for name in ("reward", "terminated", "truncated"):
        require(played[name].shape == (BATCH, STEPS, *agents), f"{name} has shape {played[name].shape[2:]}, not {agents}")
    require(played["terminated"].dtype == np.bool_ and played["truncated"].dtype == np.bool_, "terminated and truncated must be booleans")
    require(
        any(not np.array_equal(played["obs0"][0], played["obs0"][i]) for i in range(1, BATCH)),
        f"the first observation is the same in {BATCH} different worlds",
    )
    # vmap walks over the worlds: world 1 played alone, unbatched, is the batch's row 1.
    jitted = subject.jitted
    key_steps, key_reset = jax.random.split(subject.keys[1])
    obs, state = jitted.reset(key_reset, subject.world(1), subject.params)
    key_act, key_env = jax.random.split(jax.random.split(key_steps, STEPS)[0])
    step_obs, _, reward, *_ = jitted.step(key_env, state, subject.random_action(key_act), subject.params)
    alone = (np.asarray(obs), np.asarray(step_obs), np.asarray(reward))
    batched = (played["obs0"][1], played["obs"][1, 0], played["reward"][1, 0])
    require(
        all(np.allclose(a, b, rtol=1e-5, atol=1e-6) for a, b in zip(alone, batched)), "world 1 played alone differs from row 1 of the vmapped batch"
    )
    return f"{BATCH} worlds x {STEPS} steps: shapes, dtypes, and a world alone equal to its row of the batch"


@check("same key, same episode")
def same_key(subject: Subject) -> str:
    again = jax.tree_util.tree_map(np.asarray, subject.jitted.episodes(subject.keys, subject.worlds, subject.params))
    require(trees_equal(subject.played, again), "the same keys gave another episode; draw all randomness from the keys")
    other = jax.tree_util.tree_map(np.asarray, subject.jitted.episodes(jax.random.split(jax.random.key(1), BATCH), subject.worlds, subject.params))
    require(not np.array_equal(subject.played["action"], other["action"]), "other keys gave the same actions")
    return "replayed with the same keys: identical; other keys: other episodes"


@check("truncated exactly at the step limit")
def truncation(subject: Subject) -> str:
    terminated, truncated = subject.played["terminated"], subject.played["truncated"]
    if terminated.ndim > 2:  # multi-agent: an episode ends for everybody at once
        terminated, truncated = terminated.any(axis=-1), truncated.any(axis=-1)
    truncations = 0
    for ends, cuts in zip(terminated, truncated):
        first_end = int(np.argmax(ends | cuts)) if (ends | cuts).any() else STEPS
        require(first_end < STEPS, f"an episode did not end by params.max_steps = {STEPS}")
        require(not (ends[first_end] and cuts[first_end]), "terminated and truncated both true at once; they are exclusive")
        require(not cuts[:first_end].any(), "truncated before the episode's end")
        require(not cuts[first_end] or first_end == STEPS - 1, f"truncated at step {first_end + 1}, not at the limit {STEPS}")
        truncations += int(cuts[first_end])
    require(truncations, f"none of {BATCH} random-action episodes ran to a step limit of {STEPS}; the check could not see a truncation")
    return f"{truncations} of {BATCH} random-action episodes truncated at step {STEPS}, none early"


@check("autoreset onto the next world")
def autoreset(subject: Subject) -> str:
    jitted, world, next_world = subject.jitted, subject.world(0), subject.world(1)
    obs, state = jitted.reset(jax.random.key(0), world, subject.params)
    action, key = subject.random_action(jax.random.key(1)), jax.random.key(2)
    # A limit of one step ends the episode at once: the new episode starts on next_world.
    ended = short(subject.params, 1)
    new_obs, new_state, *_ = jitted.autoreset(key, state, action, ended, next_world)
    fresh_obs, fresh_state = jitted.reset(jax.random.split(key)[1], next_world, ended)
    require(
        np.allclose(np.asarray(new_obs), np.asarray(fresh_obs), rtol=1e-6), "an ended episode did not restart with reset's observation on next_world"
    )
    require(trees_equal(new_state.world, fresh_state.world), "an ended episode did not move to next_world")
    require(trees_equal(new_state.replace(world=None), fresh_state.replace(world=None)), "the restarted state is not reset's state")
    # An episode that goes on stays on its world (the next world is ignored).
    long = short(subject.params, 100)
    going_obs, going_state, _, terminated, truncated, _ = jitted.autoreset(key, state, action, long, next_world)
    if not np.any(terminated) and not np.any(truncated):
        require(trees_equal(going_state.world, state.world), "an episode that went on switched worlds")
        stepped_obs = jitted.step(jax.random.split(key)[0], state, action, long)[0]
        require(np.allclose(np.asarray(going_obs), np.asarray(stepped_obs), rtol=1e-5, atol=1e-6), "an episode that went on is not step's")
    return "an ended episode restarts on next_world as reset does; one going on keeps its world"


@check("store arrays round-trip")
def store_round_trip(subject: Subject) -> str:
    spec, worlds = subject.spec, subject.worlds
    arrays = spec.world_to_arrays(worlds)
    require(all(isinstance(value, np.ndarray) for value in arrays.values()), "world_to_arrays must give numpy arrays")
    require(trees_equal(spec.world_from_arrays(arrays), worlds), "world -> arrays -> world changed the worlds")
    require(
        trees_equal(spec.stack_worlds([spec.world_to_arrays(subject.world(i)) for i in range(BATCH)]), worlds),
        "stack_worlds of single worlds is not the batch",
    )
    problem = refuses_in_one_line(lambda: spec.world_from_arrays({**arrays, "unexpected": np.zeros(1)}))
    require(problem is None, f"a stored world with an unknown field: {problem}")
    return "world -> arrays -> world and stack_worlds exact; an unknown field refused"


def damaged(world: Any) -> Any:
    """``world`` with its first field cut by one along its last axis (the others intact)."""
    first = dataclasses.fields(world)[0].name
    return world.replace(**{first: np.asarray(getattr(world, first))[..., :-1]})


@check("a malformed world is refused in one line")
def malformed_refused(subject: Subject) -> str:
    broken = damaged(subject.world(0))
    for what, call in (
        ("check_world of a cut world", lambda: subject.env.check_world(broken)),
        ("validate() of a cut world", broken.validate),
        ("check_world of a dict", lambda: subject.env.check_world({"not": "a world"})),
    ):
        problem = refuses_in_one_line(call)
        require(problem is None, f"{what}: {problem}; raise a one-line WorldagentError")
    return "check_world and validate() refuse a cut world, check_world a non-world, each in one line"


@check("cells are binary with the declared shape")
def cells_binary(subject: Subject) -> str:
    spec = subject.spec
    cells = np.asarray(spec.cells(subject.worlds))
    expected = (BATCH, int(np.prod(spec.cell_shape)))
    require(
        cells.shape == expected and cells.shape[1] == spec.cell_count,
        f"cells have shape {cells.shape}, not {expected} (cell_shape {spec.cell_shape})",
    )
    require(cells.dtype == np.uint8 and np.isin(cells, (0, 1)).all(), f"cells must be uint8 of 0/1, not {cells.dtype}")
    return f"uint8[{BATCH}, {spec.cell_count}] of 0/1"


@check("descriptors are finite and vary")
def descriptors_vary(subject: Subject) -> str:
    """``worldagent atlas`` refuses a descriptor constant over its 512 G(z) samples."""
    descriptors = subject.spec.metrics.descriptors
    if not descriptors:
        raise Skipped("no descriptors declared (no failure atlas)")
    count = len(jax.tree_util.tree_leaves(subject.described)[0])
    worlds = [take(subject.described, i) for i in range(count)]
    for name, describe in descriptors.items():
        values = np.array([float(describe(world)) for world in worlds])
        require(np.all(np.isfinite(values)), f"descriptor {name!r} is not finite on some of the {count} worlds ({subject.source})")
        if subject.kind == DECODED:
            fix = "make it vary on repaired worlds, or leave it out of --descriptors"
            require(
                values.min() < values.max(),
                f"descriptor {name!r} is {values[0]:g} on all {count} decoded worlds ({subject.source}): `worldagent atlas` refuses it; {fix}",
            )
        else:
            require(
                values.min() < values.max(),
                f"descriptor {name!r} is {values[0]:g} on all {count} worlds of {subject.source}; `worldagent atlas` would refuse it",
            )
    return f"{', '.join(descriptors)}: finite and varying over {count} worlds ({subject.source})"


@check("episode pictures draw episodes")
def episode_pictures(subject: Subject) -> str:
    """``pictures.episodes(axis, world, episodes)`` draws an ``Episodes`` traced at its start and end; ``episode_note`` reads it."""
    from worldagent.evaluation.trajectories import Episodes
    from worldagent.reports.figures import _pyplot

    spec = subject.spec
    if spec.pictures.episodes is None:
        raise Skipped(f"{spec.name} registers no episode picture")
    _, start = subject.jitted.reset(subject.keys[0], subject.world(0), subject.params)
    final = take(subject.played["final"], 0)
    (first, first_present), (last, last_present) = spec.trace(start), spec.trace(final)
    metrics = {name: np.asarray(value)[None] for name, value in subject.env.metrics(final).items()}
    episodes = Episodes(
        positions=np.stack([first, last])[None], present=np.stack([first_present, last_present])[None], steps=np.array([1]), metrics=metrics
    )
    plt = _pyplot()
    figure, axis = plt.subplots()
    try:
        spec.pictures.episodes(axis, subject.world(0), episodes)
    finally:
        plt.close(figure)
    require(spec.episode_note is None or isinstance(spec.episode_note(episodes.metrics), str), "episode_note must return text")
    return "an episode traced by spec.trace drawn on its world" + (", episode_note read it" if spec.episode_note else "")
