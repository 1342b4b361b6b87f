"""External agents: any Python ``obs (numpy) -> action`` as a host policy, and a host-loop episode.

``CallablePolicy(fn)`` wraps a rule-based or pre-trained agent (e.g. a Stable-Baselines3
model) for host-loop evaluation; it is not jittable (``host = True``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.errors import WorldagentError


@dataclass(frozen=True)
class CallablePolicy:
    """Any Python ``fn(obs numpy) -> action`` as a policy for a host-loop evaluator.

    It is not jittable (``host = True`` tells evaluators to step it from Python). Use it for
    rule-based or pre-trained agents from other libraries, e.g.
    ``CallablePolicy(lambda obs: sb3_model.predict(obs, deterministic=True)[0])``.

    Attributes:
        fn: ``obs (numpy array) -> action`` (an int, or int[N] for multi-agent envs).
        name: for reports.
    """

    fn: Callable[[np.ndarray], Any]
    name: str = "callable"
    host = True

    def __post_init__(self):
        if not callable(self.fn):
            raise WorldagentError(f"CallablePolicy needs a callable obs -> action; got {type(self.fn).__name__}.")

    def __call__(self, obs, key=None, state=None) -> np.ndarray:
        """The action for one observation (numpy in, numpy int out)."""
        return np.asarray(self.fn(np.asarray(obs))).astype(np.int32)


def host_episode(env, policy: CallablePolicy, key: jax.Array, world: Any, env_params, max_steps: int | None = None) -> Any:
    """Play one episode with a host policy, stepping the jitted env from Python; returns the final env state."""
    reset = jax.jit(env.reset)
    step = jax.jit(env.step)
    key, key_reset = jax.random.split(key)
    obs, state = reset(key_reset, world, env_params)
    limit = int(env_params.max_steps) if max_steps is None else max_steps
    for _ in range(limit):
        key, key_step = jax.random.split(key)
        action = policy(np.asarray(obs))
        obs, state, _, terminated, truncated, _ = step(key_step, state, jnp.asarray(action), env_params)
        if bool(np.any(terminated)) or bool(np.any(truncated)):
            break
    return state
