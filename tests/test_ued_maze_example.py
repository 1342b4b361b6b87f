"""The example package ``examples/ued_maze`` (jaxued's UED maze) used as a stranger uses it (issue 42, item 3).

It registers only through the ``worldagent.envs`` entry point, so these tests run where it is installed
(CI: ``pip install -e examples/ued_maze``) and are skipped elsewhere. The conformance suite covers its env
contract; here: the registration, the ``prefabs`` world set against jaxued's own prefabs, the adapter's
episodes against jaxued's own ``Maze.step``, the BFS and the repair, and (``-m example``) the CLI's tiny
``reproduce`` through every phase.
"""

from __future__ import annotations

import math
import re
from collections import deque

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from typer.testing import CliRunner

from worldagent.cli import app
from worldagent.envs import registry
from worldagent.errors import WorldagentError

spec_module = pytest.importorskip("ued_maze.spec", reason="the ued_maze example is not installed: pip install -e examples/ued_maze")

from jaxued.environments.maze import Level  # noqa: E402  (after the skip: jaxued comes with the package)
from jaxued.environments.maze.level import prefabs as jaxued_prefabs  # noqa: E402
from ued_maze import paths, shims  # noqa: E402
from ued_maze.env import jaxued_maze  # noqa: E402
from ued_maze.repair import MazeRepair  # noqa: E402
from ued_maze.world import MAX_WALLS, PREFAB_NAMES, SIZE, from_level, generate, numpy_world, to_level  # noqa: E402

SPEC = spec_module.SPEC
STEPS = 60  # steps of each compared episode (the oracle solves the first two prefabs in fewer)
MAZE_PLR_EVAL_LEVELS = [  # jaxued's examples/maze_plr.py, default --eval_levels
    "SixteenRooms",
    "SixteenRooms2",
    "Labyrinth",
    "LabyrinthFlipped",
    "Labyrinth2",
    "StandardMaze",
    "StandardMaze2",
    "StandardMaze3",
]


def index(worlds, i):
    return jax.tree_util.tree_map(lambda leaf: np.asarray(leaf)[i], worlds)


def test_the_package_is_registered_through_its_entry_point_only():
    from importlib.metadata import entry_points

    (entry,) = [entry for entry in entry_points(group=registry.ENTRY_POINT_GROUP) if entry.name == "ued_maze"]
    assert entry.value == "ued_maze.spec:SPEC"
    assert registry.get("ued_maze") is SPEC
    assert not any("ued_maze" in module for module in registry.BUILTIN)


def test_the_shim_restores_jax_tree_map_for_jaxued():
    assert jax.tree_map is jax.tree_util.tree_map
    assert set(shims.PATCHED) <= {"jax.tree_map"}
    stacked = Level.stack([Level.from_str(jaxued_prefabs["TrivialMaze"])] * 2)  # jaxued's own call of jax.tree_map
    assert stacked.wall_map.shape == (2, 3, 3)


def test_the_prefab_set_is_jaxueds_held_out_mazes_in_order_and_round_trips_levels():
    assert list(PREFAB_NAMES) == MAZE_PLR_EVAL_LEVELS
    worlds = SPEC.world_sets["prefabs"]()
    worlds.validate()
    assert np.asarray(worlds.wall_map).shape == (len(PREFAB_NAMES), SIZE, SIZE)
    for i, name in enumerate(PREFAB_NAMES):
        level = Level.from_str(jaxued_prefabs[name]).pad_to_shape(SIZE, SIZE)
        world = index(worlds, i)
        assert world.agent_dir.shape == () and world.goal_pos.shape == (2,)
        assert np.array_equal(world.wall_map, level.wall_map) and np.array_equal(world.goal_pos, level.goal_pos), name
        assert np.array_equal(world.agent_pos, level.agent_pos) and int(world.agent_dir) == int(level.agent_dir), name
        back = to_level(world)
        assert bool(back.is_well_formatted()), name
        assert back.to_str() == level.to_str(), name
        assert jax.tree_util.tree_all(jax.tree_util.tree_map(np.array_equal, numpy_world(from_level(back)), world))
    assert SPEC.world_from_arrays(SPEC.world_to_arrays(worlds)).agent_dir.tolist() == np.asarray(worlds.agent_dir).tolist()


@pytest.fixture(scope="module")
def compared():
    """Five mazes (three generated, two prefabs) played by the adapter and by jaxued's own Maze with the same keys and actions:
    random actions (forward every other step) on the generated ones, the oracle's (which reach the goal) on the prefabs."""
    worlds = jax.tree_util.tree_map(lambda a, b: np.concatenate([a, b]), generate(np.arange(3)), index(SPEC.world_sets["prefabs"](), slice(0, 2)))
    env, params = SPEC.make_env()
    maze = jaxued_maze()
    maze_params = env.jaxued_params(params)
    actions = jax.random.randint(jax.random.key(3), (5, STEPS), 0, env.num_actions)
    actions = actions.at[:, ::2].set(2)  # forward every other step, so the agents get somewhere

    def play(key, world, moves, guided):
        obs, state = env.reset(key, world, params)
        theirs_obs, theirs = maze.reset_to_level(key, to_level(world), maze_params)

        def one(carry, move):
            state, theirs = carry
            move = jnp.where(guided, paths.oracle_action(state), move)
            obs, state, reward, terminated, truncated, _ = env.step(key, state, move, params)
            theirs_obs, theirs, their_reward, their_done, _ = maze.step(key, theirs, move, maze_params)
            ours = {"obs": obs, "pos": state.inner.agent_pos, "dir": state.inner.agent_dir, "reward": reward, "done": terminated | truncated}
            expected = {
                "obs": jnp.concatenate([theirs_obs.image.ravel(), jax.nn.one_hot(theirs_obs.agent_dir, 4)]),
                "pos": theirs.agent_pos,
                "dir": theirs.agent_dir,
                "reward": their_reward,
                "done": their_done,
            }
            return (state, theirs), (ours, expected)

        first = jnp.concatenate([theirs_obs.image.ravel(), jax.nn.one_hot(theirs_obs.agent_dir, 4)])
        return (obs, first), jax.lax.scan(one, (state, theirs), moves)[1]

    keys = jax.random.split(jax.random.key(0), 5)
    guided = jnp.arange(5) >= 3
    return worlds, jax.tree_util.tree_map(np.asarray, jax.jit(jax.vmap(play))(keys, worlds, actions, guided))


def test_the_adapter_steps_as_jaxueds_own_maze(compared):
    _, ((obs, first), (ours, theirs)) = compared
    assert np.allclose(obs, first)
    for name in ("obs", "pos", "dir", "reward"):
        assert np.allclose(ours[name].astype(np.float64), theirs[name].astype(np.float64)), name
    # Until an episode's end (jaxued's done): afterwards jaxued is no longer meant to be stepped.
    ended = np.cumsum(theirs["done"], axis=1) > np.asarray(theirs["done"], int)
    assert np.array_equal(ours["done"][~ended], theirs["done"][~ended])
    assert len({tuple(p) for p in ours["pos"].reshape(-1, 2)}) > 5, "the agents hardly moved; the comparison saw little"
    assert (theirs["reward"][3:] > 0).any(axis=1).all(), "the guided episodes never reached the goal; the rewards went untested"


def test_the_adapter_flattens_a_5x5_view_and_a_direction():
    env, _ = SPEC.make_env()
    assert env.observation_shape == (5 * 5 * 3 + 4,)
    assert env.num_actions == 7 and SPEC.make_env()[1].max_steps == 250


def python_bfs(world) -> int:
    walls, (ax, ay), (gx, gy) = np.asarray(world.wall_map, bool), world.agent_pos, world.goal_pos
    seen, queue = {(int(ax), int(ay)): 0}, deque([(int(ax), int(ay))])
    while queue:
        x, y = queue.popleft()
        for dx, dy in ((1, 0), (0, 1), (-1, 0), (0, -1)):
            nx, ny = x + dx, y + dy
            if 0 <= nx < SIZE and 0 <= ny < SIZE and not walls[ny, nx] and (nx, ny) not in seen:
                seen[(nx, ny)] = seen[(x, y)] + 1
                queue.append((nx, ny))
    return seen.get((int(gx), int(gy)), -1)


def test_the_shortest_path_descriptor_is_a_breadth_first_search():
    worlds = generate(np.arange(40))
    crowded = np.asarray(worlds.wall_map).copy()
    crowded[:, ::2, 1::2] = True  # many cut-off goals among these
    crowded_worlds = worlds.replace(wall_map=crowded)
    for batch in (worlds, crowded_worlds):
        for i in range(40):
            world = index(batch, i)
            assert SPEC.metrics.descriptors["shortest_path"](world) == python_bfs(world), i
    assert {python_bfs(index(crowded_worlds, i)) for i in range(40)} & {-1}


def test_the_generator_draws_0_to_25_walls_as_jaxueds_generator_places_them():
    worlds = generate(np.arange(256))
    worlds.validate()
    counts = np.asarray(worlds.wall_map).sum(axis=(1, 2))
    # Uniform wall draws: jaxued's generator with its fixed n_walls = 25 never gives fewer than ~17 walls.
    assert counts.min() == 0 and counts.max() <= MAX_WALLS and np.mean(counts < 8) > 0.15
    assert len(np.unique(np.asarray(worlds.agent_dir))) == 4


@pytest.mark.parametrize("walls", ["count", "threshold"])
def test_the_repair_makes_any_logits_a_valid_maze(walls):
    repair = MazeRepair.from_dataset(None, {"walls": walls})
    logits = jax.random.normal(jax.random.key(1), (64, SPEC.cell_count)) * 4.0
    logits = logits.at[:8, : SIZE * SIZE].set(30.0)  # all walls: goal and start must still be carved out
    mazes = numpy_world(jax.jit(lambda x: repair(x))(logits))
    mazes.validate()
    assert np.asarray(mazes.wall_map)[:8].sum(axis=(1, 2)).tolist() == [SIZE * SIZE - 2] * 8
    with pytest.raises(WorldagentError, match="walls='diagonal'; pick one of: count, threshold"):
        MazeRepair.from_dataset(None, {"walls": "diagonal"})


def test_the_oracle_solves_every_prefab_along_a_shortest_path():
    from worldagent.envs.core import rollout

    env, params = SPEC.make_env()
    policy = SPEC.scripted["oracle"](env, params)
    worlds = SPEC.world_sets["prefabs"]()
    final, _ = jax.jit(jax.vmap(lambda world: rollout(env, policy, jax.random.key(0), world, params, params.max_steps)))(worlds)
    metrics = jax.tree_util.tree_map(np.asarray, jax.vmap(env.metrics)(final))
    assert metrics["solved"].all()
    moves = np.array([python_bfs(index(worlds, i)) for i in range(len(PREFAB_NAMES))])
    assert np.all(metrics["episode_length"] >= moves) and np.all(metrics["episode_length"] <= 3 * moves + 2)
    assert np.allclose(metrics["return"], 1.0 - 0.9 * metrics["episode_length"] / params.max_steps)


@pytest.mark.example  # its own step in .ci/run, outside the default run's 5 minutes
def test_reproduce_tiny_runs_every_phase_on_the_ued_maze(tmp_path):
    result = CliRunner().invoke(app, ["reproduce", "--preset", "tiny", "--env", "ued_maze", "--out", str(tmp_path), "--quiet"])
    assert result.exit_code == 0, result.output
    html = (tmp_path / "report.html").read_text()
    assert "<h3>ued_maze</h3>" in html
    values = dict(re.findall(r'data-key="([^"]+)" data-value="([^"]+)"', html))
    assert math.isfinite(float(values["ued_maze.random.mean_raw"]))
    assert 0.0 <= float(values["ued_maze.random.mean_normalised"]) <= 1.0
    assert any(key.startswith("ued_maze.atlas") for key in values), "the atlas phase left nothing in the report"
