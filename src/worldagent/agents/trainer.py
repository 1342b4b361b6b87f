"""The trainer contract every algorithm meets (DESIGN.md "Trainer"), PureJaxRL style.

``make_train(config, env, params, distribution, training_params=None) -> Trainer``, where
``training_params`` is the env's ``EnvSpec.training_params`` (the params a learner trains
under, e.g. racing's respawn-on-crash; the host driver passes it)::

    trainer = make_train(config, env, params, distribution)
    state, curve = trainer.train(key)                     # the whole run, one jitted call
    states, curves = jax.vmap(trainer.train)(keys)        # several seeds at once
    state = trainer.init(key)
    state, rows = trainer.train_chunk(state, n)           # n updates; what the host driver runs

The state has ``params``, ``update`` (i32 updates done), ``episodes``, ``env_steps`` and ``key``
(raw u32 key data, so a checkpoint holds it and a resumed run continues identically). Each
curve entry is f32[n], one row per update; updates after the episode budget is spent are
skipped (``lax.cond``), their rows NaN and ``active`` 0, so chunking never changes the result.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np


class Program(NamedTuple):
    """A trainer's jitted functions with their arguments explicit, for a driver that vmaps runs (``many.py``).

    Attributes:
        init: ``init(key, consts) -> state``.
        chunk: ``chunk(state, n, budget, consts) -> (state, curve)``, ``n`` static.
        consts: what this trainer passes as ``consts`` (env params, world distribution, ...).
        budget: i32[2], the episode budget and the env-step budget (``budget_spent``).
    """

    init: Callable
    chunk: Callable
    consts: Any
    budget: jax.Array


class Trainer(NamedTuple):
    """What an algorithm's ``make_train`` returns (all pure; ``train_chunk`` and ``train`` jitted).

    Attributes:
        init: ``init(key) -> state``.
        train_chunk: ``train_chunk(state, n) -> (state, curve)``, ``n`` updates (static); each
            curve entry is f32[n] (``active`` 1 where the update ran).
        train: ``train(key) -> (state, curve)``, the whole budget (``max_updates`` rows).
        network: the Flax module the policy acts with.
        max_updates: updates that surely spend the budget.
        done: ``done(state) -> bool``, the budget is spent.
        program: the same functions with their ``consts`` as arguments (``Program``).
    """

    init: Callable
    train_chunk: Callable
    train: Callable
    network: Any
    max_updates: int
    done: Callable
    program: Program | None = None


def raw_key(key: jax.Array) -> jax.Array:
    """u32 key data (serialisable with msgpack) of a typed or raw PRNG key."""
    return jax.random.key_data(key) if jnp.issubdtype(key.dtype, jax.dtypes.prng_key) else key


def curve_row(values: dict) -> dict:
    """A curve row: every entry an f32 scalar."""
    return {name: jnp.asarray(value, jnp.float32) for name, value in values.items()}


NO_STEP_BUDGET = np.iinfo(np.int32).max  # env steps of a run budgeted by episodes alone


def budget_spent(state, budget) -> jax.Array:
    """bool: the run has ended ``budget[0]`` episodes or taken ``budget[1]`` env steps."""
    return jnp.logical_or(state.episodes >= budget[0], state.env_steps >= budget[1])


@functools.lru_cache(maxsize=32)
def _jitted(init: Callable, update: Callable) -> tuple[Callable, Callable]:
    """Jitted ``init`` and chunk of ``init``/``update`` (cached: trainers built from the same functions compile once)."""

    def chunk(state, n: int, budget, consts):
        def skip(state):
            shapes = jax.eval_shape(update, state, consts)[1]
            return state, {k: jnp.float32(0.0) if k == "active" else jnp.full(s.shape, jnp.nan, s.dtype) for k, s in shapes.items()}

        def guarded(state, _):
            return jax.lax.cond(budget_spent(state, budget), skip, lambda s: update(s, consts), state)

        return jax.lax.scan(guarded, state, None, length=n)

    return jax.jit(init), jax.jit(chunk, static_argnums=1)


def budgeted_trainer(
    init: Callable, update: Callable, total_episodes: int, budget: int, network: Any, consts: Any = None, total_env_steps: int = 0
) -> Trainer:
    """A ``Trainer`` from ``init(key, consts) -> state`` and ``update(state, consts) -> (state, curve row)``.

    Training stops once ``total_episodes`` episodes have ended or, when ``total_env_steps`` > 0,
    that many env steps are taken, whichever comes first (``budget`` updates surely spend it).

    ``consts`` (env params, the world distribution) are passed into the jitted functions as
    arguments, not baked into the compiled program. ``train(key)`` is the jitted ``init``
    followed by one jitted chunk of ``budget`` updates, so it shares its compilations with the
    host driver (whose chunks have ``budget`` updates when they are the whole run) and with
    other trainers built from the same ``init`` and ``update`` objects; ``jax.vmap`` and
    ``jax.jit`` of it work as of any pure function.
    """
    init_jit, chunk = _jitted(init, update)
    total = jnp.array([total_episodes, total_env_steps or NO_STEP_BUDGET], jnp.int32)
    return Trainer(
        init=lambda key: init_jit(key, consts),
        train_chunk=lambda state, n: chunk(state, n, total, consts),
        train=lambda key: chunk(init_jit(key, consts), budget, total, consts),
        network=network,
        max_updates=budget,
        done=lambda state: bool(budget_spent(state, total)),
        program=Program(init_jit, chunk, consts, total),
    )
