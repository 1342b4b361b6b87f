"""Objectives: what a campaign optimises, and how a latent becomes a score (paper §4.4, §5.2.2).

An objective is a per-episode metric of the environment and a direction. A latent z is scored
by generating its world G(z), rolling the agents out ``repeats`` times on it (the paper: 8),
and averaging the metric over those episodes::

    racing:  return, normalised_return, crashed (its mean is the crash rate), lap_completed,
             progress, steps
    harvest: group_reward, conflict, equality, sustainability, peace

Each episode's metrics are kept with the evaluation, raw values beside normalised ones.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.errors import WorldagentError
from worldagent.evaluation.local import evaluate
from worldagent.search.campaign import Outcome

METRICS = {
    "racing": ("return", "normalised_return", "crashed", "lap_completed", "progress", "steps"),
    "harvest": ("group_reward", "conflict", "equality", "sustainability", "peace"),
}


ALIASES = {"reward": {"racing": "return", "harvest": "group_reward"}}  # the paper's main metric


def metric_name(env: str, name: str) -> str:
    """``name``, with "reward" meaning each env's main reward metric (paper §4.4)."""
    return ALIASES.get(name, {}).get(env, name)


@dataclass(frozen=True)
class Objective:
    """A metric of ``env``'s episodes and the direction to push it."""

    env: str
    metric: str
    maximize: bool

    def __post_init__(self):
        if self.env not in METRICS:
            raise WorldagentError(f"unknown environment {self.env!r}; use one of: {', '.join(METRICS)}.")
        if self.metric not in METRICS[self.env]:
            raise WorldagentError(f"{self.env} has no metric {self.metric!r}; use one of: {', '.join(METRICS[self.env])}.")


def with_derived_metrics(env_name: str, metrics: dict[str, np.ndarray], params: Any) -> dict[str, np.ndarray]:
    """Add the metrics computed from others (racing: the normalised return, paper §6)."""
    if env_name == "racing":
        from worldagent.agents.metrics import normalised_return

        metrics = {**metrics, "normalised_return": np.asarray(normalised_return(metrics["return"], params))}
    return metrics


def episode_records(metrics: dict[str, np.ndarray], world: int) -> list[dict]:
    """The episodes of world ``world`` as one dict of plain numbers (or lists) per episode."""
    repeats = next(iter(metrics.values())).shape[1]
    return [{name: np.asarray(value[world, r]).tolist() for name, value in metrics.items()} for r in range(repeats)]


@jax.jit
def _generate(generator, z):
    return generator(z)


class LatentObjective:
    """``evaluate(z[n, dim], seeds[n]) -> [Outcome]`` for ``run_campaign``: G(z), then episodes.

    Args:
        objective: the metric and direction.
        env: the environment; ``params`` its parameters (default: the env's).
        policy: the agents (an ``agents.policy.Policy``).
        generator: G (a ``worlds.generator.Generator``).
        repeats: episodes per world (the paper: 8).
        keep_worlds: store each generated world with its evaluation.
    """

    def __init__(self, objective: Objective, env, policy, generator, repeats: int = 8, params: Any = None, keep_worlds: bool = True):
        if generator.env != objective.env:
            raise WorldagentError(f"the generator makes {generator.env} worlds but the objective is a {objective.env} metric.")
        self.objective, self.env, self.policy, self.generator = objective, env, policy, generator
        self.repeats, self.keep_worlds = int(repeats), keep_worlds
        self.params = env.default_params if params is None else params

    def __call__(self, z: np.ndarray, seeds: np.ndarray) -> list[Outcome]:
        self.generator.check_latents(np.asarray(z))
        worlds = _generate(self.generator, jnp.asarray(z, jnp.float32))
        keys = jnp.stack([jax.random.split(jax.random.key(int(seed)), self.repeats) for seed in seeds])
        metrics = evaluate(self.env, self.policy, worlds, self.repeats, None, self.params, keys=keys)
        metrics = with_derived_metrics(self.objective.env, metrics, self.params)
        scores = np.asarray(metrics[self.objective.metric], np.float64).mean(axis=1)
        outcomes = []
        for b in range(len(z)):
            world = jax.tree_util.tree_map(lambda leaf: np.asarray(leaf[b]), worlds) if self.keep_worlds else None
            outcomes.append(Outcome(float(scores[b]), episode_records(metrics, b), world))
        return outcomes
