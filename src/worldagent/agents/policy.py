"""Policies as values (DESIGN.md "Policy"): one calling convention everywhere.

A ``Policy`` is a pytree (its parameters are leaves; its ``act`` function is static), so it
can be passed into jitted, vmapped evaluation code::

    action = policy.act(policy.params, obs, key, state)     # pure JAX

``state`` (the env state) is only read by *privileged* scripted policies such as the racing
reference driver; every other policy ignores it.

A policy may carry **memory** (a recurrent PPO agent): then ``initial_memory`` is a pytree (one
episode's, e.g. an LSTM's (c, h) f32[M] each) and ``step(params, obs, key, state, memory) ->
(action, memory)`` acts; a memoryless policy has ``initial_memory=None`` and no ``step``. Every
loop plays both through ``envs.core.policy_step`` (its one adapter), starting each episode from
``initial_memory``; a memoryless policy's memory stays None, so its keys and results are those
of ``act``. Trained networks become policies with
``network_policy``; saved agents are read by ``saved.load_policy``, ``--agent`` strings by
``loaders.load_agent``. External agents (ONNX, Python callables, Stable-Baselines3) are
``external.HostPolicy`` values: numpy in, numpy out, stepped by the host evaluator.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from worldagent.agents.networks import initial_memory
from worldagent.errors import WorldagentError


@dataclass(frozen=True)
class AgentSource:
    """What an agent is, recorded with every campaign it plays (provenance).

    Attributes:
        kind: "worldagent" (a saved policy), "scripted", "onnx", "callable", "sb3" or "python".
        path: the directory, file, ``module:function`` or scripted name the agent came from.
        sha256: a hash of its file(s) (None for scripted and in-memory agents).
    """

    kind: str
    path: str
    sha256: str | None = None

    def record(self) -> dict:
        """As stored in a campaign's config."""
        return asdict(self)


def agent_record(policy: Any) -> dict:
    """What ``policy`` is, as campaigns record it: its ``source``; for agents built in Python, their name and a hash
    of their parameters (two trained agents of one name are two agents: DESIGN.md "Identity")."""
    source = getattr(policy, "source", None)
    if source is None:
        params = getattr(policy, "params", None)
        source = AgentSource("python", str(getattr(policy, "name", type(policy).__name__)), params_hash(params) if params is not None else None)
    return source.record()


def params_hash(params: Any) -> str:
    """sha256 over a parameter pytree's leaves (shapes, dtypes and bytes, in tree order)."""
    digest = hashlib.sha256()
    for leaf in jax.tree_util.tree_leaves(params):
        value = np.ascontiguousarray(np.asarray(leaf))
        digest.update(f"{value.dtype.str}{value.shape}".encode())
        digest.update(value.tobytes())
    return digest.hexdigest()


def file_hash(*paths: Path) -> str:
    """sha256 over the bytes of ``paths`` (in the order given)."""
    digest = hashlib.sha256()
    for path in paths:
        digest.update(Path(path).read_bytes())
    return digest.hexdigest()


@struct.dataclass
class Policy:
    """A policy value.

    Attributes:
        params: the policy's parameters (a pytree; None for parameter-free policies).
        act: ``act(params, obs, key, state) -> action`` (static, pure JAX).
        name: what it is, for reports (static).
        privileged: True when ``act`` reads the env ``state`` (scripted drivers) (static).
        source: where the agent came from (``AgentSource``; None for agents built in Python) (static).
        initial_memory: the memory an episode starts with (a pytree), or None: memoryless.
        step: ``step(params, obs, key, state, memory) -> (action, memory)`` of a policy with
            memory (static); None: memoryless.
    """

    params: Any
    act: Callable = struct.field(pytree_node=False)
    name: str = struct.field(pytree_node=False, default="policy")
    privileged: bool = struct.field(pytree_node=False, default=False)
    source: AgentSource | None = struct.field(pytree_node=False, default=None)
    initial_memory: Any = None
    step: Callable | None = struct.field(pytree_node=False, default=None)


def network_act(module, kind: str, greedy: bool = False, num_agents: int = 1, epsilon: float = 0.0) -> Callable:
    """``act(params, obs, key, state=None)`` of a network of ``kind`` ("actor_critic": sample the
    categorical, or its argmax when ``greedy``; "q_network": argmax of the action values, a
    uniformly random action with probability ``epsilon``)."""

    def act_one(params, obs, key):
        out = module.apply(params, obs)
        scores = out[0] if kind == "actor_critic" else out
        if kind == "actor_critic" and not greedy:
            return jax.random.categorical(key, scores).astype(jnp.int32)
        best = jnp.argmax(scores, axis=-1).astype(jnp.int32)
        if epsilon <= 0.0:
            return best
        key_explore, key_action = jax.random.split(key)
        random_action = jax.random.randint(key_action, best.shape, 0, scores.shape[-1])
        return jnp.where(jax.random.uniform(key_explore, best.shape) < epsilon, random_action, best)

    def act(params, obs, key, state=None):
        del state
        if num_agents == 1:
            return act_one(params, obs, key)
        return jax.vmap(act_one)(params, obs, jax.random.split(key, num_agents))

    return act


def recurrent_step(module, greedy: bool = False) -> Callable:
    """``step(params, obs, key, state, memory) -> (action, memory)`` of a recurrent actor-critic
    (``networks.ActorCritic`` with ``recurrent``): sample its categorical, or argmax when ``greedy``."""

    def step(params, obs, key, state, memory):
        del state
        logits, _, memory = module.apply(params, obs, memory)
        action = jnp.argmax(logits, axis=-1) if greedy else jax.random.categorical(key, logits)
        return action.astype(jnp.int32), memory

    return step


def memoryless_only(params, obs, key, state=None):
    """The ``act`` of a policy with memory: refused, as acting without its memory would be wrong."""
    raise WorldagentError("this policy carries memory (a recurrent agent); step it with envs.core.policy_step, which threads its memory.")


def network_policy(module, params, kind: str, greedy: bool = False, num_agents: int = 1, name: str | None = None, epsilon: float = 0.0) -> Policy:
    """A trained network as a ``Policy`` (see ``network_act``; ``recurrent_step`` for an actor-critic with memory)."""
    mode = "stochastic" if kind == "actor_critic" and not greedy else (f"epsilon {epsilon:g}" if epsilon > 0 else "greedy")
    cell = getattr(module, "recurrent", None)
    if cell is None:
        return Policy(params, network_act(module, kind, greedy, num_agents, epsilon), name or f"{kind} ({mode})")
    if num_agents != 1:
        raise WorldagentError(f"a recurrent {kind} is a single agent's; this one has {num_agents} stacked: save each agent's network on its own.")
    memory = initial_memory(cell, module.memory_size)
    return Policy(params, memoryless_only, name or f"{kind} {cell} ({mode})", initial_memory=memory, step=recurrent_step(module, greedy))
