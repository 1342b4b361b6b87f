"""Objectives: what a campaign optimises, and how a latent becomes a score (paper §4.4, §5.2.2).

An objective is a per-episode metric of the environment and a direction. A latent z is scored
by generating its world G(z), rolling the agents out ``repeats`` times on it (the paper: 8),
and averaging the metric over those episodes. The metrics, their aliases ("reward" is the
env's main metric, racing ``crash_rate`` is ``crashed``) and the derived ones (racing's
normalised return) come from the env's registration (``EnvSpec.metrics``).

Each episode's metrics are kept with the evaluation, raw values beside derived ones.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.evaluation.local import evaluate
from worldagent.search.campaign import Outcome


@dataclass(frozen=True)
class Objective:
    """A metric of ``env``'s episodes and the direction to push it.

    Attributes:
        env: the registered environment's name.
        metric: a metric or alias of it; stored as the canonical name (``reward`` -> the main one).
        maximize: the direction.
    """

    env: str
    metric: str
    maximize: bool

    def __post_init__(self):
        spec = registry.get(self.env)
        object.__setattr__(self, "env", spec.name)
        object.__setattr__(self, "metric", spec.metrics.resolve(self.metric, spec.name))


def episode_records(metrics: dict[str, np.ndarray], world: int) -> list[dict]:
    """The episodes of world ``world`` as one dict of plain numbers (or lists) per episode."""
    repeats = next(iter(metrics.values())).shape[1]
    return [{name: np.asarray(value[world, r]).tolist() for name, value in metrics.items()} for r in range(repeats)]


LATENTS_PER_CALL = 32  # G(z) always decodes this many latents at once (see ``generate``): a generation of 21 pads to 32


@functools.partial(jax.jit, static_argnames="logits")
def _decode(generator, z, logits: bool = False):
    return generator.logits(z) if logits else generator(z)


def generate(generator, z, logits: bool = False) -> Any:
    """G(z) for latents z f[n, dim] (shared by every campaign), in calls of ``LATENTS_PER_CALL``;
    with ``logits``, the decoder's f32[n, D] cell logits instead of the repaired worlds.

    The decoder's matrix products round differently for different batch sizes, and a repair
    that picks the nearest world or the top-k cells can tip on the last bit; one call shape
    makes a latent's world depend on the latent alone, as its episodes do (``evaluation.local``).
    """
    z = jnp.asarray(z, jnp.float32)
    parts = []
    for start in range(0, len(z), LATENTS_PER_CALL):
        chunk = z[start : start + LATENTS_PER_CALL]
        padded = jnp.concatenate([chunk, jnp.repeat(chunk[-1:], LATENTS_PER_CALL - len(chunk), axis=0)])
        parts.append(jax.tree_util.tree_map(lambda leaf, n=len(chunk): leaf[:n], _decode(generator, padded, logits)))
    return jax.tree_util.tree_map(lambda *leaves: jnp.concatenate(leaves), *parts)


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
        self.spec = registry.get(objective.env)
        self.repeats, self.keep_worlds = int(repeats), keep_worlds
        self.params = env.default_params if params is None else params

    def __call__(self, z: np.ndarray, seeds: np.ndarray) -> list[Outcome]:
        self.generator.check_latents(np.asarray(z))
        worlds = generate(self.generator, jnp.asarray(z, jnp.float32))
        return play_outcomes(self.objective, self.env, self.policy, worlds, seeds, self.repeats, self.params, self.keep_worlds)


def search_keys(seed: int, repeats: int) -> jax.Array:
    """The ``[repeats]`` episode keys of a world a search scores with ``seed`` (``campaign.evaluation_seed``)."""
    return jax.random.split(jax.random.key(int(seed)), int(repeats))


def play_outcomes(
    objective: Objective,
    env,
    policy,
    worlds: Any,
    seeds: np.ndarray,
    repeats: int,
    params: Any,
    keep_worlds: bool = True,
    keys_of: Any = search_keys,
) -> list[Outcome]:
    """The outcome of each of ``worlds`` (batched, one per seed): the world played ``repeats`` times with its seed's
    keys (``keys_of(seed, repeats)``: a search's, or ``analysis.confirm.confirmation_keys``), scored by the
    objective's metric averaged over those episodes (raw and derived metrics kept per episode)."""
    spec = registry.get(objective.env)
    keys = jnp.stack([keys_of(int(seed), repeats) for seed in seeds])
    metrics = spec.metrics.with_derived(evaluate(env, policy, worlds, repeats, None, params, keys=keys), params)
    scores = np.asarray(metrics[objective.metric], np.float64).mean(axis=1)
    outcomes = []
    for b in range(len(seeds)):
        world = jax.tree_util.tree_map(lambda leaf: np.asarray(leaf[b]), worlds) if keep_worlds else None
        outcomes.append(Outcome(float(scores[b]), episode_records(metrics, b), world))
    return outcomes
