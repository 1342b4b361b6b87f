"""Policies as values (DESIGN.md "Policy"): trained networks, scripted drivers and external callables.

A ``Policy`` is a pytree (its parameters are leaves; its ``act`` function is static), so it
can be passed into jitted, vmapped evaluation code::

    action = policy.act(policy.params, obs, key, state)     # pure JAX
    action = policy(obs, key, state)                         # the same, params bound

``act(policy_params, obs, key, state=None)`` is the contract; ``state`` (the env state) is
only read by *privileged* scripted policies such as the racing reference driver, which
follows the track's centreline from the state; every other policy ignores it.

Saved agents (``save_policy`` / ``load_policy``) are a directory of ``policy.msgpack`` (the
parameters, ``flax.serialization``) and ``policy.json`` (format version, algorithm, env,
network architecture and its config, observation shape, number of actions, number of agents,
training config). A multi-agent agent (e.g. 4 independent DQNs) stacks its agents' parameters
on a leading axis of size ``num_agents``; ``act`` then maps each agent's network over its own
observation ``obs[N, ...] -> action[N]``. Nothing is pickled.

``CallablePolicy(fn)`` wraps any Python ``obs (numpy) -> action`` (a rule-based or pre-trained
agent, e.g. a Stable-Baselines3 model) for host-loop evaluation (``host_episode``).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import flax.serialization
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from worldagent.agents.networks import build_network, network_config
from worldagent.errors import WorldagentError
from worldagent.files import write_bytes

FORMAT_VERSION = 1
PARAMS_FILE = "policy.msgpack"
CONFIG_FILE = "policy.json"


@struct.dataclass
class Policy:
    """A policy value.

    Attributes:
        params: the policy's parameters (a pytree; None for parameter-free policies).
        act: ``act(params, obs, key, state=None) -> action`` (static, pure JAX).
        name: what it is, for reports (static).
        privileged: True when ``act`` reads the env ``state`` (scripted drivers) (static).
    """

    params: Any
    act: Callable = struct.field(pytree_node=False)
    name: str = struct.field(pytree_node=False, default="policy")
    privileged: bool = struct.field(pytree_node=False, default=False)

    def __call__(self, obs: jax.Array, key: jax.Array, state: Any = None) -> jax.Array:
        """``act(params, obs, key, state)``."""
        return self.act(self.params, obs, key, state)

    def as_rollout_policy(self) -> Callable:
        """``policy(key, obs, state) -> action`` for ``envs.core.rollout``."""
        return lambda key, obs, state: self.act(self.params, obs, key, state)


# -- trained networks --------------------------------------------------------------------------


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


def network_policy(module, params, kind: str, greedy: bool = False, num_agents: int = 1, name: str | None = None, epsilon: float = 0.0) -> Policy:
    """A trained network as a ``Policy`` (see ``network_act``)."""
    mode = "stochastic" if kind == "actor_critic" and not greedy else (f"epsilon {epsilon:g}" if epsilon > 0 else "greedy")
    return Policy(params, network_act(module, kind, greedy, num_agents, epsilon), name or f"{kind} ({mode})")


@dataclass(frozen=True)
class SavedPolicy:
    """A loaded agent: its ``Policy`` and what ``policy.json`` says about it.

    Attributes:
        policy: the policy value (``load_policy``'s ``greedy`` picks its mode).
        module: the Flax module (rebuilt from its config).
        kind: network architecture name.
        algorithm: "ppo", "acktr", "dqn", ...
        env: "racing" or "harvest".
        obs_shape: one agent's observation shape.
        num_actions: A.
        num_agents: agents stacked on the parameters' leading axis (1: no agent axis).
        training: the training config (a dict) the agent was trained with.
        extra: anything else the trainer recorded (episodes, env steps, ...).
    """

    policy: Policy
    module: Any
    kind: str
    algorithm: str
    env: str
    obs_shape: tuple[int, ...]
    num_actions: int
    num_agents: int
    training: dict
    extra: dict

    @property
    def params(self) -> Any:
        return self.policy.params


def _init_params(module, obs_shape, num_agents: int) -> Any:
    """A template of the module's parameters (stacked over agents when ``num_agents > 1``)."""
    init = lambda key: module.init(key, jnp.zeros(obs_shape, jnp.float32))  # noqa: E731
    if num_agents == 1:
        return jax.eval_shape(init, jax.random.key(0))
    return jax.eval_shape(jax.vmap(init), jax.random.split(jax.random.key(0), num_agents))


def save_policy(
    directory: str | Path,
    module,
    params: Any,
    *,
    kind: str,
    algorithm: str,
    env: str,
    obs_shape: tuple[int, ...],
    num_actions: int,
    num_agents: int = 1,
    training: dict | None = None,
    extra: dict | None = None,
) -> Path:
    """Write a trained agent to ``directory`` (``policy.msgpack`` + ``policy.json``), atomically.

    Args:
        directory: where to write (created if missing).
        module: the Flax module (its fields must be JSON-able; see ``networks.network_config``).
        params: its parameters; with ``num_agents > 1``, stacked on a leading agent axis.
        kind: its architecture name in ``networks.NETWORKS`` ("actor_critic", "q_network", ...).
        algorithm: the training algorithm ("ppo", "acktr", "dqn").
        env: "racing" or "harvest".
        obs_shape: one agent's observation shape.
        num_actions: A.
        num_agents: agents stacked in ``params`` (1 for a single agent).
        training: the training config as a JSON-able dict.
        extra: other JSON-able facts (episodes trained, env steps, seed, ...).
    """
    build_network(kind, network_config(module))  # refuses unknown kinds before writing anything
    template = _init_params(module, tuple(obs_shape), num_agents)
    _check_params_match(params, template, "the parameters to save")
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    config = {
        "format_version": FORMAT_VERSION,
        "algorithm": algorithm,
        "env": env,
        "network": {"kind": kind, "config": network_config(module)},
        "obs_shape": list(obs_shape),
        "num_actions": int(num_actions),
        "num_agents": int(num_agents),
        "training": training or {},
        "extra": extra or {},
    }
    write_bytes(directory / PARAMS_FILE, flax.serialization.to_bytes(jax.device_get(params)))
    write_bytes(directory / CONFIG_FILE, json.dumps(config, indent=1).encode())
    return directory


def load_policy(directory: str | Path, env: str | None = None, greedy: bool = False, algorithm: str | None = None) -> SavedPolicy:
    """Read an agent saved by ``save_policy``; refuses other versions, envs, algorithms or architectures.

    Args:
        directory: the agent's directory.
        env: if given, the env the agent must be for.
        greedy: act by argmax: actor-critics instead of sampling, Q-networks without the
            exploration rate their trainer recorded (``extra["act_epsilon"]``).
        algorithm: if given, the algorithm it must have been trained with.
    """
    directory = Path(directory)
    remedy = "train it again with `worldagent train`"
    try:
        config = json.loads((directory / CONFIG_FILE).read_text())
        blob = (directory / PARAMS_FILE).read_bytes()
    except OSError:
        raise WorldagentError(f"{directory} holds no saved policy ({CONFIG_FILE} and {PARAMS_FILE}); {remedy}.") from None
    except ValueError:
        raise WorldagentError(f"{directory / CONFIG_FILE} is not valid JSON; {remedy}.") from None
    version = config.get("format_version") if isinstance(config, dict) else None
    if version != FORMAT_VERSION:
        raise WorldagentError(f"{directory} holds a policy of format version {version}; this worldagent reads version {FORMAT_VERSION}; {remedy}.")
    if env is not None and config["env"] != env:
        raise WorldagentError(f"{directory} holds a {config['env']} agent, not a {env} agent; pass an agent trained on {env}.")
    if algorithm is not None and config["algorithm"] != algorithm:
        raise WorldagentError(f"{directory} holds a {config['algorithm']} agent, not a {algorithm} agent; pass a {algorithm} checkpoint.")
    kind = config["network"]["kind"]
    module = build_network(kind, config["network"]["config"])
    obs_shape, num_agents = tuple(config["obs_shape"]), int(config["num_agents"])
    template = _init_params(module, obs_shape, num_agents)
    try:
        state = flax.serialization.msgpack_restore(blob)
    except Exception:  # msgpack raises several types on corrupt data
        raise WorldagentError(f"{directory / PARAMS_FILE} is corrupted; {remedy}.") from None
    params = _restore_params(template, state, f"{directory / PARAMS_FILE}")
    # Q-network agents act as their trainer recorded (e.g. DQN's act_epsilon), unless asked to be greedy.
    epsilon = 0.0 if greedy else float(config.get("extra", {}).get("act_epsilon", 0.0))
    policy = network_policy(module, params, kind, greedy, num_agents, name=f"{config['algorithm']} {kind} ({directory.name})", epsilon=epsilon)
    return SavedPolicy(
        policy,
        module,
        kind,
        config["algorithm"],
        config["env"],
        obs_shape,
        int(config["num_actions"]),
        num_agents,
        config.get("training", {}),
        config.get("extra", {}),
    )


def _restore_params(template: Any, state: Any, what: str) -> Any:
    """``state`` (a restored msgpack dict) shaped like ``template``; other architectures are refused."""
    try:
        params = flax.serialization.from_state_dict(template, state)
    except (ValueError, KeyError, TypeError) as error:
        raise WorldagentError(
            f"{what} does not fit the recorded architecture ({str(error).splitlines()[0][:120]}); it is from another network."
        ) from None
    _check_params_match(params, template, what)
    return jax.tree_util.tree_map(jnp.asarray, params)


def _check_params_match(params: Any, template: Any, what: str) -> None:
    """Same tree structure and leaf shapes as ``template``, else ``WorldagentError``."""
    got, want = jax.tree_util.tree_structure(params), jax.tree_util.tree_structure(template)
    if got != want:
        raise WorldagentError(f"{what} have a different layer structure than the architecture; they are from another network.")
    for leaf, spec in zip(jax.tree_util.tree_leaves(params), jax.tree_util.tree_leaves(template)):
        if np.shape(leaf) != spec.shape:
            raise WorldagentError(
                f"{what} hold a layer of shape {np.shape(leaf)} where the architecture has {spec.shape}; they are from another network."
            )


# -- scripted reference policies ----------------------------------------------------------------


def racing_driver_policy(env_params=None, driver=None) -> Policy:
    """The racing reference driver (``envs/racing/driver.py``) as a privileged ``Policy``."""
    from worldagent.envs.racing.driver import DriverParams, driver_action
    from worldagent.envs.racing.env import RacingParams

    env_params = RacingParams() if env_params is None else env_params
    driver = DriverParams() if driver is None else driver

    def act(params, obs, key, state=None):
        if state is None:
            raise WorldagentError("the racing driver reads the env state; pass state to act (it is a privileged policy).")
        return driver_action(state, *params)

    return Policy((env_params, driver), act, "racing driver", privileged=True)


def harvest_random_policy() -> Policy:
    """Harvest's uniform random policy (``envs/harvest/policies.py``): obs[4, ...] -> action[4]."""
    from worldagent.envs.harvest.policies import random_act

    return Policy(None, lambda params, obs, key, state=None: random_act(params, obs, key), "harvest random")


def harvest_greedy_policy(env=None) -> Policy:
    """Harvest's greedy apple-seeker (``envs/harvest/policies.py``): obs[4, ...] -> action[4]."""
    from worldagent.envs.harvest.env import Harvest
    from worldagent.envs.harvest.policies import greedy_policy

    greedy = greedy_policy(Harvest() if env is None else env)
    return Policy(None, lambda params, obs, key, state=None: greedy(params, obs, key), "harvest greedy")


def scripted_policy(env: str, name: str) -> Policy:
    """A scripted policy by name: racing "driver"; harvest "random" or "greedy"."""
    table = {("racing", "driver"): racing_driver_policy, ("harvest", "random"): harvest_random_policy, ("harvest", "greedy"): harvest_greedy_policy}
    if (env, name) not in table:
        known = ", ".join(f"{e}/{n}" for e, n in table)
        raise WorldagentError(f"no scripted policy {name!r} for {env}; known: {known}.")
    return table[(env, name)]()


# -- external callables (host loop) --------------------------------------------------------------


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
