"""A UED maze: jaxued's ``Level`` as a worldagent world, its procedural generator and its held-out prefabs.

``MazeWorld`` holds one maze or a batch (a leading axis on every field) with jaxued's field names and
conventions: positions are (x, y) = (column, row), ``wall_map[y, x]``, directions 0 right, 1 down,
2 left, 3 up. ``to_level`` / ``from_level`` convert to and from jaxued's ``Level``; the generator
and the prefabs are jaxued's own (``make_level_generator``, ``Level.load_prefabs``), called here.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jaxued.environments.maze import Level, make_level_generator

from worldagent.errors import WorldagentError

SIZE = 13  # jaxued's Maze(max_height=13, max_width=13)
CELLS = SIZE * SIZE
DIRECTIONS = 4
MAX_WALLS = 25  # jaxued's default --n_walls
# The held-out mazes jaxued's examples/maze_plr.py evaluates on (its default --eval_levels), in its order.
PREFAB_NAMES = ("SixteenRooms", "SixteenRooms2", "Labyrinth", "LabyrinthFlipped", "Labyrinth2", "StandardMaze", "StandardMaze2", "StandardMaze3")
CELL_CHANNELS = ("walls", "goal", "agent facing right", "agent facing down", "agent facing left", "agent facing up")
GENERATE_CHUNK = 256  # seeds per generator call: one compiled program for any number of seeds


@struct.dataclass
class MazeWorld:
    """One maze (jaxued's ``Level`` on the fixed 13×13 grid).

    Attributes:
        wall_map: bool[..., 13, 13], True on wall cells, indexed ``[y, x]``.
        goal_pos: i32[..., 2], the goal's (x, y).
        agent_pos: i32[..., 2], the agent's start (x, y).
        agent_dir: i32[...], the agent's start direction (0 right, 1 down, 2 left, 3 up).
    """

    wall_map: np.ndarray
    goal_pos: np.ndarray
    agent_pos: np.ndarray
    agent_dir: np.ndarray

    def validate(self) -> None:
        """Raise ``WorldagentError`` unless every maze is well formed (jaxued's ``Level.is_well_formatted``, strictly)."""
        walls, goal, agent, direction = (np.asarray(field) for field in (self.wall_map, self.goal_pos, self.agent_pos, self.agent_dir))
        batch = walls.shape[:-2]
        if walls.shape[-2:] != (SIZE, SIZE) or goal.shape != (*batch, 2) or agent.shape != (*batch, 2) or direction.shape != batch:
            raise WorldagentError(
                f"maze fields have shapes {walls.shape}, {goal.shape}, {agent.shape}, {direction.shape}; "
                f"expected [..., {SIZE}, {SIZE}], [..., 2], [..., 2], [...] (build mazes with ued_maze.world.generate or from_level)."
            )
        if not np.isin(walls, (0, 1)).all():
            raise WorldagentError("maze wall_map must be 0/1; threshold it first.")
        for name, value, high in (("goal_pos", goal, SIZE), ("agent_pos", agent, SIZE), ("agent_dir", direction, DIRECTIONS)):
            if not np.issubdtype(value.dtype, np.integer) or value.min(initial=0) < 0 or value.max(initial=0) >= high:
                raise WorldagentError(f"maze {name} must hold integers in [0, {high}); got {value.dtype} {value.min()}..{value.max()}.")
        flat_walls = walls.reshape(-1, SIZE, SIZE).astype(bool)
        for index, ((gx, gy), (ax, ay)) in enumerate(zip(goal.reshape(-1, 2), agent.reshape(-1, 2))):
            if (gx, gy) == (ax, ay):
                raise WorldagentError(f"maze {index} has its goal on the agent's start {(int(ax), int(ay))}; move one of them.")
            if flat_walls[index, gy, gx] or flat_walls[index, ay, ax]:
                raise WorldagentError(f"maze {index} has its goal or start on a wall; clear those cells.")


def to_level(world: MazeWorld) -> Level:
    """jaxued's ``Level`` of a maze (or a batch), with jaxued's dtypes (uint32 positions, uint8 direction)."""
    return Level(
        wall_map=jnp.asarray(world.wall_map, jnp.bool_),
        goal_pos=jnp.asarray(world.goal_pos, jnp.uint32),
        agent_pos=jnp.asarray(world.agent_pos, jnp.uint32),
        agent_dir=jnp.asarray(world.agent_dir, jnp.uint8),
        width=SIZE,
        height=SIZE,
    )


def from_level(level: Level) -> MazeWorld:
    """The maze of a jaxued ``Level`` (or a stacked batch); a smaller level is padded with walls to 13×13 as jaxued pads it.

    Raises:
        WorldagentError: the level is larger than 13×13.
    """
    height, width = np.shape(level.wall_map)[-2:]
    if height > SIZE or width > SIZE:
        raise WorldagentError(f"a {width}x{height} jaxued level does not fit the {SIZE}x{SIZE} maze; use levels of at most {SIZE}x{SIZE}.")
    level = level.pad_to_shape(SIZE, SIZE)
    return MazeWorld(
        wall_map=jnp.asarray(level.wall_map, jnp.bool_),
        goal_pos=jnp.asarray(level.goal_pos, jnp.int32),
        agent_pos=jnp.asarray(level.agent_pos, jnp.int32),
        agent_dir=jnp.asarray(level.agent_dir, jnp.int32),
    )


def numpy_world(world: MazeWorld) -> MazeWorld:
    """The same maze(s) with numpy fields (what the store and the conformance suite compare)."""
    return jax.tree_util.tree_map(np.asarray, world)


def seed_keys(seeds: np.ndarray) -> jax.Array:
    """One PRNG key per int64 seed: the seed's high and low 32 bits folded in turn into key 0 (no two seeds share a key)."""
    seeds = np.asarray(seeds, np.int64).astype(np.uint64)
    high, low = (seeds >> np.uint64(32)).astype(np.uint32), (seeds & np.uint64(0xFFFFFFFF)).astype(np.uint32)
    fold = lambda h, lo: jax.random.fold_in(jax.random.fold_in(jax.random.key(0), h), lo)
    return jax.vmap(fold)(jnp.asarray(high), jnp.asarray(low))


def sample(key: jax.Array) -> MazeWorld:
    """One maze from jaxued's scattered-wall generator with ``n ~ U{0..25}`` wall draws.

    jaxued's ``make_level_generator(13, 13, n_walls)`` places ``n_walls`` wall draws (with
    replacement), then the agent (uniform position and direction) and the goal on free cells. Its
    fixed ``n_walls`` becomes a uniform draw up to jaxued's default 25 (minimax's scheme, commented out
    in jaxued's generator), so the dataset spans empty to crowded mazes.
    """
    key_count, key_level = jax.random.split(key)
    n_walls = jax.random.randint(key_count, (), 0, MAX_WALLS + 1)
    return from_level(make_level_generator(SIZE, SIZE, n_walls)(key_level))


_sample_many = jax.jit(jax.vmap(sample))


def generate(seeds) -> MazeWorld:
    """The procedural generator: one maze per seed, deterministic.

    Args:
        seeds: int64[N] seeds.

    Returns:
        MazeWorld with numpy fields and a leading axis N.
    """
    seeds = np.asarray(seeds, np.int64).reshape(-1)
    padded = np.concatenate([seeds, np.zeros(-len(seeds) % GENERATE_CHUNK, np.int64)])
    chunks = [numpy_world(_sample_many(seed_keys(padded[i : i + GENERATE_CHUNK]))) for i in range(0, len(padded), GENERATE_CHUNK)]
    return jax.tree_util.tree_map(lambda *parts: np.concatenate(parts)[: len(seeds)], *chunks)


def one_hot_cells(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """uint8[N, 13·13]: the cell (x[n], y[n]) of each maze set."""
    grid = np.zeros((len(x), CELLS), np.uint8)
    grid[np.arange(len(x)), np.asarray(y) * SIZE + np.asarray(x)] = 1
    return grid


def cells(worlds: MazeWorld) -> np.ndarray:
    """uint8[N, 6·13·13]: the VAE's input, ``CELL_CHANNELS`` flattened: the walls, the goal's cell, then the agent's
    start as one cell of four direction planes (its position and direction are one categorical choice)."""
    walls = np.asarray(worlds.wall_map, np.uint8).reshape(-1, CELLS)
    goal, agent = np.asarray(worlds.goal_pos).reshape(-1, 2), np.asarray(worlds.agent_pos).reshape(-1, 2)
    direction = np.asarray(worlds.agent_dir).reshape(-1)
    facing = np.zeros((len(walls), DIRECTIONS, CELLS), np.uint8)
    facing[np.arange(len(walls)), direction] = one_hot_cells(agent[:, 0], agent[:, 1])
    return np.concatenate([walls, one_hot_cells(goal[:, 0], goal[:, 1]), facing.reshape(len(walls), -1)], axis=1)


@functools.cache
def prefab_levels() -> Level:
    """jaxued's held-out prefabs ``PREFAB_NAMES``, stacked by ``Level.load_prefabs`` (built once)."""
    return Level.load_prefabs(list(PREFAB_NAMES))


def prefabs() -> MazeWorld:
    """The named world set ``prefabs``: jaxued's eight held-out mazes in ``PREFAB_NAMES``' order (numpy, leading axis 8)."""
    return numpy_world(from_level(prefab_levels()))
