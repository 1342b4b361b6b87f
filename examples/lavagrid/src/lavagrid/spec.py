"""The lava grid's ``EnvSpec``: everything worldagent needs to know about it.

Built with worldagent's public API only; the package's ``pyproject.toml`` names ``SPEC`` in the
``worldagent.envs`` entry-point group, so once installed every ``worldagent`` command accepts
``lavagrid``. Its rewards are on the scale of ±1, so PPO trains with its own defaults: the spec
declares no ``algorithm_overrides``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.envs.registry import EnvSpec, Metrics, Pictures, ScriptedPolicy
from worldagent.envs.repairs import NearestWorld

from . import pictures
from .env import LavaGridEnv
from .repair import raw_decode
from .world import SIZE, START, LavaGrid, cells, generate

NAME = "lavagrid"


def make(options):
    """``LavaGridEnv()`` and its default params (the lava grid has no options)."""
    del options
    env = LavaGridEnv()
    return env, env.default_params


def bounds(params) -> tuple[float, float]:
    """The return's range: stepping into lava on the last step, and reaching the goal in one step."""
    low = -float(params.lava_penalty) - float(params.step_penalty) * float(params.max_steps)
    return low, float(params.goal_reward) - float(params.step_penalty)


def trace(state):
    """(position i32[2] (row, col), present): the one agent is always on the grid."""
    return state.position, jnp.bool_(True)


def uniform(env, params) -> ScriptedPolicy:
    """Uniformly random moves: the baseline a trained agent must beat."""
    return ScriptedPolicy(None, lambda p, obs, key, state: jax.random.randint(key, (), 0, env.num_actions))


def episode_note(metrics: dict) -> str:
    """ ", 3/8 episodes reached the goal, 2/8 burned"."""
    reached, burned = np.asarray(metrics.get("reached", []), bool), np.asarray(metrics.get("burned", []), bool)
    if not len(reached):
        return ""
    return f", {int(reached.sum())}/{len(reached)} episodes reached the goal, {int(burned.sum())}/{len(burned)} burned"


def training_check(means) -> str:
    """Why a trained agent failed to learn ("" if it reaches the goal in a quarter of its episodes or
    more; PPO's reaches it in 60% of episodes on 1,000 G(z) worlds, uniformly random moves in 11%)."""
    reached, burned = means.get("reached"), means.get("burned", 0.0)
    if reached is None or reached >= 0.25:
        return ""
    how = "it burns in lava" if burned > 1.0 - reached - burned else "it wanders until the time limit"
    return f"reaches the goal in only {reached:.0%} of its episodes ({how})"


def lava_share(world) -> float:
    """Fraction of the cells that are lava."""
    return float(np.asarray(world.lava, bool).mean())


def goal_distance(world) -> float:
    """Manhattan distance from the start to the goal, cells."""
    row, col = np.unravel_index(int(np.argmax(np.asarray(world.goal))), (SIZE, SIZE))
    return float(abs(row - START[0]) + abs(col - START[1]))


SPEC = EnvSpec(
    name=NAME,
    description="Lava grid (examples/lavagrid): walk from the top-left cell of an 11x11 grid to the goal without stepping into lava.",
    make=make,
    world_type=LavaGrid,
    generate=generate,
    cells=cells,
    cell_shape=(2, SIZE, SIZE),
    repair=NearestWorld.from_dataset,  # the dataset world nearest to the decoded cells (repair.py says why)
    metrics=Metrics(
        main="return",
        names=("return", "reached", "burned", "steps"),
        aliases={"reach_rate": "reached", "burn_rate": "burned"},
        bounds=bounds,
        compared=("return", "reached", "burned"),
        highlighted=("reached", "burned"),
        descriptors={"lava_share": lava_share, "goal_distance": goal_distance},
        default_descriptors=("lava_share", "goal_distance"),
    ),
    trace=trace,
    pictures=Pictures(world=pictures.world_picture, episodes=pictures.draw_episodes, sheet=pictures.sheet),
    scripted={"random": uniform},
    algorithms=("ppo",),
    presets={
        "tiny": {
            "worlds": 256,
            "vae_epochs": 3,
            "episodes": 64,
            "random_worlds": 16,
            "strategic_budget": 21,
            "compare_budget": 0,
            "compare_seeds": (0,),
            "influence_candidates": 32,
            "influence_episodes": 64,
            "influence_eval_worlds": 8,
            "influence_seeds": (0,),
            "train_envs": 8,
        },
    },
    selection="reached < 0.5",
    failure="burned > 0.5",
    training_check=training_check,
    episode_note=episode_note,
    raw_decode=raw_decode,
)
