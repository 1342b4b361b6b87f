"""The training algorithms, one table: name -> config class, ``make_train``, saved network kind.

Every command, reproduce phase and influencing experiment picks its algorithm and config here.
A config is the algorithm's defaults (its papers'), then the env's departures
(``EnvSpec.training_settings``), then the caller's fields (the CLI's ``--set``)::

    config = training_config(spec, episodes=500)         # the spec's default algorithm (racing: ppo)
    config = training_config(spec, "acktr", num_envs=8)  # another algorithm, a field overridden
    settings = parse_settings(["ppo.learning_rate=1e-3"], ["ppo"])  # {"ppo": {"learning_rate": 0.001}}
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from worldagent.agents import acktr, dqn, ppo
from worldagent.configs import describe_field, parse_field
from worldagent.envs import registry
from worldagent.errors import WorldagentError


@dataclass(frozen=True)
class Algorithm:
    """A training algorithm the host driver (``training.train``) runs.

    Attributes:
        name: "ppo", "acktr", "dqn".
        config_type: its frozen config dataclass (``configs.JsonConfig``: ``budget_field``,
            ``with_episodes``, ``to_dict``/``from_dict``).
        make_train: ``make_train(config, env, env_params, distribution, training_params=None) ->
            trainer.Trainer`` (``training_params``: the env's ``EnvSpec.training_params``).
        network_kind: the saved agent's architecture name (``networks.NETWORKS``).
        learning_potential: what a curriculum's buffer scores its episodes by (``curricula``).
    """

    name: str
    config_type: type
    make_train: Callable
    network_kind: str
    learning_potential: str


ALGORITHMS: dict[str, Algorithm] = {
    "ppo": Algorithm("ppo", ppo.PPOConfig, ppo.make_train, "actor_critic", "positive value loss"),
    "acktr": Algorithm("acktr", acktr.ACKTRConfig, acktr.make_train, "actor_critic", "positive value loss"),
    "dqn": Algorithm("dqn", dqn.DQNConfig, dqn.make_train, "q_network", "|TD error|"),
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
            departures, ``spec.training_settings(algo, options)``).
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
        config = algorithm.config_type().replace(**spec.training_settings(algo, options))
    elif isinstance(base, algorithm.config_type):
        config = base
    else:
        raise WorldagentError(f"algorithm {algo!r} takes a {algorithm.config_type.__name__}, not a {type(base).__name__}.")
    if episodes is not None:
        config = config.with_episodes(episodes)
    return config.replace(**overrides) if overrides else config


# -- ``--set NAME=VALUE``: config fields from the command line -------------------------------------


def parse_settings(texts: Iterable[str], algos: Iterable[str]) -> dict[str, dict[str, Any]]:
    """Config fields from ``NAME=VALUE`` texts (the CLI's ``--set``), each parsed to its field's type.

    ``NAME`` sets that field of every algorithm in ``algos`` whose config has it; ``ALGO.NAME``
    only of ``ALGO``. A name no algorithm in ``algos`` has, or a value of the wrong type, is
    refused in one line naming the valid fields or the expected type.

    Args:
        texts: the ``--set`` texts, e.g. ``["learning_rate=1e-3", "ppo.hidden=64,64"]``.
        algos: the algorithms the run trains (``train``: one; ``reproduce``: each env's).

    Returns:
        ``{algo: {field: value}}`` for every algorithm in ``algos`` (empty where nothing is set).
    """
    algos = list(dict.fromkeys(algos))
    settings: dict[str, dict[str, Any]] = {algo: {} for algo in algos}
    for text in texts:
        name, sep, value = text.partition("=")
        prefix, dot, field_name = name.strip().rpartition(".")
        if not sep or not field_name:
            raise WorldagentError(f"--set {text!r}: write NAME=VALUE, e.g. --set learning_rate=1e-3 (or ALGO.NAME=VALUE).")
        if dot and prefix not in algos:
            raise WorldagentError(f"--set {text!r}: this run trains {', '.join(algos)}, not {prefix!r}; write NAME=VALUE or one of those as ALGO.")
        targets = [prefix] if dot else algos
        hints = {algo: typing.get_type_hints(get_algorithm(algo).config_type) for algo in targets}
        having = [algo for algo in targets if field_name in hints[algo]]
        if not having:
            elsewhere = [algo for algo in ALGORITHMS if field_name in typing.get_type_hints(ALGORITHMS[algo].config_type)]
            if elsewhere:  # e.g. recurrent=lstm with acktr: say which algorithm has it
                raise WorldagentError(
                    f"--set {text!r}: {field_name!r} is a setting of {'/'.join(elsewhere)}; train with --algo {elsewhere[0]} or drop it."
                )
            valid = sorted({f.name for algo in targets for f in dataclasses.fields(get_algorithm(algo).config_type)})
            raise WorldagentError(f"--set {text!r}: {'/'.join(targets)} has no setting {field_name!r}; valid: {', '.join(valid)}.")
        for algo in having:
            hint = hints[algo][field_name]
            try:
                settings[algo][field_name] = parse_field(value.strip(), hint)
            except ValueError:
                raise WorldagentError(f"--set {text!r}: {algo} {field_name} takes {describe_field(hint)}.") from None
    return settings
