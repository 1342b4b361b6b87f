"""The UED maze's ``EnvSpec``: everything worldagent needs to know about jaxued's maze.

Built with worldagent's public API only; the package's ``pyproject.toml`` names ``SPEC`` in the
``worldagent.envs`` entry-point group, so once installed every ``worldagent`` command accepts
``ued_maze``. jaxued's rewards lie in [0, 1], so PPO trains with its own defaults.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from worldagent.envs.registry import EnvSpec, Metrics, Pictures
from worldagent.envs.repairs import NearestWorld

from . import pictures
from .env import UedMazeEnv
from .paths import oracle, shortest_path, uniform, wall_count
from .repair import MazeRepair, raw_decode
from .world import CELL_CHANNELS, SIZE, MazeWorld, cells, generate, prefabs

NAME = "ued_maze"


def make(options):
    """``UedMazeEnv()`` and its default params (jaxued's defaults; the maze has no options)."""
    del options
    env = UedMazeEnv()
    return env, env.default_params


def bounds(params) -> tuple[float, float]:
    """The return's range: 0 (the goal never reached) to 1 (jaxued's goal reward, ``1 - 0.9·t / max_steps``, at t -> 0)."""
    del params
    return 0.0, 1.0


def trace(state):
    """(position i32[2] (row, col), present): the one agent is always in the maze."""
    x, y = state.inner.agent_pos[0], state.inner.agent_pos[1]
    return jnp.stack([y, x]).astype(jnp.int32), jnp.bool_(True)


def episode_note(metrics: dict) -> str:
    """ ", 3/8 episodes solved"."""
    solved = np.asarray(metrics.get("solved", []), bool)
    return f", {int(solved.sum())}/{len(solved)} episodes solved" if len(solved) else ""


def training_check(means) -> str:
    """Why a trained agent failed to learn: "" if it solves at least a quarter of its episodes (uniformly random
    actions solve 10% of 1,000 generated mazes within 250 steps, the oracle 99.9%: 0.1% are cut off)."""
    solved = means.get("solved")
    if solved is None or solved >= 0.25:
        return ""
    return f"solves only {solved:.0%} of its episodes (it wanders until the time limit)"


SPEC = EnvSpec(
    name=NAME,
    description="jaxued's UED maze (examples/ued_maze): 13x13, scattered walls, a 5x5 partial view with a direction; reach the goal.",
    make=make,
    world_type=MazeWorld,
    generate=generate,
    cells=cells,
    cell_shape=(len(CELL_CHANNELS), SIZE, SIZE),
    repair=MazeRepair.from_dataset,
    repairs={"open": MazeRepair.from_dataset, "nearest": NearestWorld.from_dataset},
    metrics=Metrics(
        main="return",
        names=("return", "solved", "episode_length"),
        aliases={"solve_rate": "solved", "steps": "episode_length"},
        bounds=bounds,
        compared=("return", "solved", "episode_length"),
        highlighted=("solved",),
        descriptors={"wall_count": wall_count, "shortest_path": shortest_path},
        default_descriptors=("wall_count", "shortest_path"),
    ),
    trace=trace,
    pictures=Pictures(
        world=pictures.world_picture, episodes=pictures.draw_episodes, sheet=pictures.sheet, locate=pictures.locate, legend=pictures.LEGEND
    ),
    scripted={"random": uniform, "oracle": oracle},
    algorithms=("ppo", "acktr"),
    presets={
        "tiny": {
            "worlds": 256,
            "vae_epochs": 3,
            "episodes": 64,
            "random_worlds": 16,
            "strategic_budget": 21,
            "compare_budget": 0,
            "compare_seeds": (0,),
            "influence_candidates": 16,
            "influence_episodes": 32,
            "influence_eval_worlds": 4,
            "influence_seeds": (0,),
            "atlas_budget": 100,
            "failure_worlds": 32,
            "train_envs": 8,
        },
        "quick": {
            "worlds": 5_000,
            "vae_epochs": 50,
            "episodes": 2_000,
            "random_worlds": 200,
            "strategic_budget": 105,
            "compare_budget": 42,
            "bo_budget": 21,
            "compare_seeds": (0,),
            "influence_candidates": 200,
            "influence_episodes": 2_000,
            "influence_eval_worlds": 50,
            "influence_seeds": (0,),
            "atlas_budget": 105,
            "failure_worlds": 100,
        },
    },
    selection="solved < 0.5",
    failure="solved < 0.5",
    training_check=training_check,
    episode_note=episode_note,
    raw_decode=raw_decode,
    world_sets={"prefabs": prefabs},
)
