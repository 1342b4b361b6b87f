"""The training algorithms, one table: name -> config class, ``make_train``, saved network kind.

Every command, reproduce phase and influencing experiment picks its algorithm and config here::

    config = training_config(spec, episodes=500)         # the spec's default algorithm (racing: ppo)
    config = training_config(spec, "acktr", num_envs=8)  # another algorithm, a field overridden
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from worldagent.agents import acktr, dqn, ppo
from worldagent.envs import registry
from worldagent.errors import WorldagentError


@dataclass(frozen=True)
class Algorithm:
    """A training algorithm the host driver (``training.train``) runs.

    Attributes:
        name: "ppo", "acktr", "dqn".
        config_type: its frozen config dataclass (``configs.JsonConfig``: ``budget_field``,
            ``with_episodes``, ``to_dict``/``from_dict``).
        make_train: ``make_train(config, env, env_params, distribution) -> trainer.Trainer``.
        network_kind: the saved agent's architecture name (``networks.NETWORKS``).
    """

    name: str
    config_type: type
    make_train: Callable
    network_kind: str


ALGORITHMS: dict[str, Algorithm] = {
    "ppo": Algorithm("ppo", ppo.PPOConfig, ppo.make_train, "actor_critic"),
    "acktr": Algorithm("acktr", acktr.ACKTRConfig, acktr.make_train, "actor_critic"),
    "dqn": Algorithm("dqn", dqn.DQNConfig, dqn.make_train, "q_network"),
}


def get_algorithm(name: str) -> Algorithm:
    """The algorithm called ``name``; unknown names are refused with the known ones."""
    if name not in ALGORITHMS:
        raise WorldagentError(f"unknown algorithm {name!r}; use one of: {', '.join(ALGORITHMS)}.")
    return ALGORITHMS[name]


def training_config(
    spec: Any, algo: str | None = None, episodes: int | None = None, base: Any = None, options: Mapping[str, Any] | None = None, **overrides
) -> Any:
    """The config an env trains ``algo`` with.

    Args:
        spec: the environment (an ``EnvSpec`` or its name).
        algo: one of ``spec.algorithms``; default ``spec.default_algorithm``.
        episodes: the episode budget (PPO/ACKTR ``total_episodes``, DQN ``num_episodes``).
        base: a config to start from (default: the algorithm's defaults with the env's
            ``spec.algorithm_overrides[algo]`` and ``spec.option_overrides(algo, options)``).
        options: the env options the agent trains with (default: the env's defaults).
        **overrides: config fields to set last (unknown ones are refused).

    Returns:
        A frozen config of the algorithm's ``config_type``.
    """
    spec = registry.get(spec)
    algo = spec.default_algorithm if algo is None else algo
    algorithm = get_algorithm(algo)
    if algo not in spec.algorithms:
        raise WorldagentError(f"{spec.name} trains with {', '.join(spec.algorithms)}, not {algo}; pick one of those.")
    if base is None:
        tuned = spec.option_overrides(algo, spec.check_options(options)) if spec.option_overrides else {}
        config = algorithm.config_type().replace(**{**spec.algorithm_overrides.get(algo, {}), **tuned})
    elif isinstance(base, algorithm.config_type):
        config = base
    else:
        raise WorldagentError(f"algorithm {algo!r} takes a {algorithm.config_type.__name__}, not a {type(base).__name__}.")
    if episodes is not None:
        config = config.with_episodes(episodes)
    return config.replace(**overrides) if overrides else config
