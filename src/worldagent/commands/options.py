"""Options the commands share: the environment argument, ``--option``, ``--agent``, counts.

Help texts that list environments are built from the registry when a command registers, so an
environment registered by a plugin shows up in ``--help`` with no edit here.
"""

from __future__ import annotations

import typer

from worldagent.envs import registry
from worldagent.errors import WorldagentError

AGENT_HELP = (
    "The agent: a `worldagent train` run directory (or the agent directory in it), a scripted policy (`worldagent envs` lists them), "
    "a .onnx model, a Stable-Baselines3 .zip, or module:function (a Python callable obs batch -> actions, from the working directory)."
)
STOCHASTIC_HELP = "External agents that return logits sample their action (with the episode's key) instead of taking the argmax."
GENERATOR_HELP = "Generator directory (from `worldagent generator train`)."
OPTION_HELP = "An environment option NAME=VALUE, e.g. tagger=0 for harvest (repeatable; `worldagent envs` lists them)."
QUIET_HELP = "No progress bars."


def env_help() -> str:
    """``Environment: racing, harvest (`worldagent envs` describes them).`` from the registry."""
    return f"Environment: {', '.join(registry.names())} (`worldagent envs` describes them)."


def metric_help() -> str:
    """The metrics each registered environment offers, for ``--metric`` / ``--objective``."""
    listed = "; ".join(f"{name}: {'|'.join(registry.get(name).metrics.names)}" for name in registry.names())
    return f"Metric: reward (the environment's main one), or {listed}."


def env_argument():
    """The ``ENV`` argument of a command (evaluated when the command registers)."""
    return typer.Argument(..., help=env_help())


def option_flag():
    """The repeatable ``--option NAME=VALUE``."""
    return typer.Option([], "--option", help=OPTION_HELP)


def stochastic_flag():
    """``--stochastic``: external agents sample from their logits."""
    return typer.Option(False, "--stochastic", help=STOCHASTIC_HELP)


def backend_flag():
    """``--backend``: where campaigns evaluate their world batches."""
    return typer.Option("local", "--backend", help="Where world batches are evaluated: local (every local device) or ray (extra `ray`).")


def ray_address_flag():
    """``--ray-address``: a Ray cluster to join."""
    return typer.Option(None, "--ray-address", help="A running Ray cluster to join (`ray start --head` prints it); default: start a local one.")


def backend(name: str, address: str | None):
    """The backend of ``--backend`` / ``--ray-address``."""
    from worldagent.evaluation.backends import make_backend

    return make_backend(name, address)


def env_options(env: str, texts: list[str]) -> dict:
    """The options of ``env`` parsed from ``--option`` texts (checked, defaults filled in)."""
    return registry.get(env).parse_options(list(texts))


def given_options(env: str, texts: list[str]) -> dict:
    """Only the options ``--option`` names (parsed, checked): ``experiments.setup`` fills the rest
    from the agent's own (a saved agent records those it trained with), then the defaults."""
    return registry.get(env).parse_options(list(texts), fill=False)


def check_counts(**counts: int) -> None:
    """Each named count must be at least 1 (one-line error naming the option)."""
    for option, value in counts.items():
        if value < 1:
            raise WorldagentError(f"--{option.replace('_', '-')} is {value}; it must be at least 1.")


def algorithm(env: str, algo: str | None) -> str:
    """``algo``, or the env's default algorithm; one the env does not train with is refused."""
    spec = registry.get(env)
    algo = algo or spec.default_algorithm
    if algo not in spec.algorithms:
        raise WorldagentError(f"unknown algorithm {algo!r} for {spec.name}; use one of: {', '.join(spec.algorithms)}.")
    return algo


def algo_help() -> str:
    """``--algo`` help: each environment's algorithms, the default first."""
    listed = "; ".join(f"{name}: {', '.join(registry.get(name).algorithms)}" for name in registry.names())
    return f"Training algorithm (default: the environment's first): {listed}."
