"""The toy gridworld's ``EnvSpec``: what the upper layers need to know about it.

Built with the public API only (``worldagent.envs.registry``); nothing in ``src/`` knows it.
``toy_env.registered()`` adds it to the registry for the duration of a test.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.envs.registry import EnvSpec, Metrics, Pictures, ScriptedPolicy

from . import pictures
from .env import MOVES, ToyGrid
from .repair import ToyRepair, raw_decode
from .world import SIZE, Grid, cells, generate

NAME = "toy"


def make(options):
    """``ToyGrid()`` and its default params (the toy has no options)."""
    del options
    env = ToyGrid()
    return env, env.default_params


def bounds(params) -> tuple[float, float]:
    """The return's range: never reaching the goal, and reaching it in one step."""
    return -float(params.step_penalty) * float(params.max_steps), float(params.goal_reward) - float(params.step_penalty)


def trace(state):
    """(position i32[2] (row, col), present): the one agent is always on the grid."""
    return state.position, jnp.bool_(True)


def uniform(env, params) -> ScriptedPolicy:
    """Uniformly random moves."""
    return ScriptedPolicy(None, lambda p, obs, key, state: jax.random.randint(key, (), 0, env.num_actions))


def homing(env, params) -> ScriptedPolicy:
    """Close the larger row/column gap to the goal, the other one when a wall blocks it (read from the observation)."""
    side, cells = env.size, env.size * env.size
    moves = jnp.asarray(MOVES)

    def act(p, obs, key, state):
        walls = obs[:cells].reshape(side, side)
        goal, agent = jnp.argmax(obs[cells : 2 * cells]), jnp.argmax(obs[2 * cells :])
        here = jnp.stack([agent // side, agent % side])
        gap = jnp.stack([goal // side, goal % side]) - here
        vertical, horizontal = jnp.array([jnp.sign(gap[0]), 0]), jnp.array([0, jnp.sign(gap[1])])
        rows_first = jnp.abs(gap[0]) >= jnp.abs(gap[1])
        first, second = jnp.where(rows_first, vertical, horizontal), jnp.where(rows_first, horizontal, vertical)
        target = jnp.clip(here + first, 0, side - 1)
        wanted = jnp.where(walls[target[0], target[1]] > 0, second, first)
        return jnp.argmax(jnp.all(moves == wanted, axis=-1)).astype(jnp.int32)

    return ScriptedPolicy(None, act)


def episode_note(metrics: dict) -> str:
    """ ", 3/8 episodes reached the goal"."""
    reached = np.asarray(metrics.get("reached", []), bool)
    return f", {int(reached.sum())}/{len(reached)} episodes reached the goal" if len(reached) else ""


def wall_share(world) -> float:
    """Fraction of the cells that are walls."""
    return float(np.asarray(world.walls, bool).mean())


def goal_distance(world) -> float:
    """Manhattan distance from the start to the goal, cells."""
    row, col = np.unravel_index(int(np.argmax(np.asarray(world.goal))), (SIZE, SIZE))
    return float(row + col)


SPEC = EnvSpec(
    name=NAME,
    description="Toy gridworld (tests/toy_env): walk from the top-left cell to the goal around random walls.",
    make=make,
    world_type=Grid,
    generate=generate,
    cells=cells,
    cell_shape=(2, SIZE, SIZE),
    repair=ToyRepair.from_dataset,
    metrics=Metrics(
        main="return",
        names=("return", "reached", "steps"),
        aliases={"reach_rate": "reached"},
        bounds=bounds,
        compared=("return", "reached"),
        highlighted=("reached",),
        descriptors={"wall_share": wall_share, "goal_distance": goal_distance},
        default_descriptors=("wall_share", "goal_distance"),
        meanings={"return": "the toy's episode reward (higher is better)", "reached": "1 if the agent reached the goal, else 0"},
    ),
    trace=trace,
    pictures=Pictures(world=pictures.world_picture, episodes=pictures.draw_episodes, sheet=pictures.sheet),
    scripted={"random": uniform, "homing": homing},
    algorithms=("ppo",),
    # Episodes last at most 30 steps: small updates and a small network learn the grid (and compile fast).
    algorithm_overrides={
        "ppo": {"num_envs": 8, "num_steps": 32, "num_minibatches": 2, "update_epochs": 2, "hidden": (32, 32), "learning_rate": 1e-3}
    },
    presets={
        "tiny": {
            "worlds": 256,
            "vae_epochs": 3,
            "episodes": 64,
            "random_worlds": 16,
            "strategic_budget": 21,
            "compare_budget": 0,  # the optimiser comparison is skipped: it is racing's and harvest's to show
            "compare_seeds": (0,),
            "influence_candidates": 32,
            "influence_episodes": 64,
            "influence_eval_worlds": 8,
            "influence_seeds": (0,),
            "train_envs": 8,
        },
    },
    selection="reached < 0.5",
    episode_note=episode_note,
    raw_decode=raw_decode,
)
