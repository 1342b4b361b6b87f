"""Saved agents: a directory of ``policy.msgpack`` (the parameters, ``flax.serialization``) and
``policy.json`` (format version, algorithm, env, network architecture and its config,
observation shape, number of actions, number of agents, training config). Nothing is pickled.

A multi-agent agent (e.g. 4 independent DQNs) stacks its agents' parameters on a leading axis
of size ``num_agents``; its policy maps each agent's network over its own observation
``obs[N, ...] -> action[N]``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import flax.serialization
import jax
import jax.numpy as jnp
import numpy as np

from worldagent.agents.networks import build_network, network_config
from worldagent.agents.policy import Policy, network_policy
from worldagent.errors import WorldagentError
from worldagent.files import write_bytes

FORMAT_VERSION = 1
PARAMS_FILE = "policy.msgpack"
CONFIG_FILE = "policy.json"


@dataclass(frozen=True)
class SavedPolicy:
    """A loaded agent: its ``Policy`` and what ``policy.json`` says about it.

    Attributes:
        policy: the policy value (``load_policy``'s ``greedy`` picks its mode).
        module: the Flax module (rebuilt from its config).
        kind: network architecture name.
        algorithm: "ppo", "acktr", "dqn", ...
        env: the registered environment's name.
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
        env: the registered environment's name.
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


def load_policy(directory: str | Path, env: Any = None, greedy: bool = False, algorithm: str | None = None) -> SavedPolicy:
    """Read an agent saved by ``save_policy``; refuses other versions, envs, algorithms or architectures.

    Args:
        directory: the agent's directory.
        env: if given, the env (a name or an ``EnvSpec``) the agent must be for.
        greedy: act by argmax: actor-critics instead of sampling, Q-networks without the
            exploration rate their trainer recorded (``extra["act_epsilon"]``).
        algorithm: if given, the algorithm it must have been trained with.
    """
    directory = Path(directory)
    env = getattr(env, "name", env)
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
