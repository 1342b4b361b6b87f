"""Pictures: Figure-5 colours, the observation view, episode GIFs, and `worldagent maps`."""

from __future__ import annotations

import jax
import numpy as np
from PIL import Image
from typer.testing import CliRunner

from worldagent.cli import app
from worldagent.envs.harvest import render
from worldagent.envs.harvest.world import DEFAULT_SIZE, HarvestMap, index_maps

runner = CliRunner()
WORLD = HarvestMap.from_str(
    """
    ......
    .#A...
    ......
    ......
    ......
    """
)


def test_state_colours_follow_figure_5(env, reset_fn, quiet_params):
    _, state = reset_fn(jax.random.key(0), WORLD, quiet_params)
    image = np.asarray(render.draw_state(state, env, observer=0, cell=10))
    assert image.shape == (50, 60, 3)
    assert tuple(image[5, 5]) == render.OBSERVER  # agent 0 at (0, 0), the observer, is blue
    assert tuple(image[5, 55]) == render.AGENT  # agent 1 at (0, 5) is red
    assert tuple(image[15, 15]) == render.WALL
    assert tuple(image[15, 25]) == render.APPLE
    assert tuple(image[25, 35]) == render.BACKGROUND


def test_observation_picture_and_episode_gif(env, reset_fn, step_fn, quiet_params, tmp_path):
    obs, state = reset_fn(jax.random.key(0), WORLD, quiet_params)
    view = render.draw_observation(np.asarray(obs[0]), cell=4)
    assert view.size == (60, 60)
    states = [state]
    for t in range(3):
        _, state, *_ = step_fn(jax.random.key(t), state, np.array([1, 1, 1, 1]), quiet_params)
        states.append(state)
    stacked = jax.tree_util.tree_map(lambda *x: np.stack(x), *[s.replace(world=None) for s in states]).replace(world=WORLD)
    path = render.save_episode_gif(stacked, tmp_path / "episode.gif", env)
    with Image.open(path) as gif:
        assert 1 < gif.n_frames <= 4  # Pillow merges identical consecutive frames


def test_worlds_command_draws_a_sheet_of_maps(tmp_path, generated_maps):
    out = tmp_path / "maps.png"
    result = runner.invoke(app, ["worlds", "harvest", "--n", "4", "--seed", "0", "--out", str(out)])
    assert result.exit_code == 0, result.output
    with Image.open(out) as image:
        sheet = np.asarray(image.convert("RGB"))
    assert image.size == (2 * (DEFAULT_SIZE * 8 + 4) + 4,) * 2
    first = np.asarray(render.draw_map(index_maps(generated_maps, 0), cell=8))
    np.testing.assert_array_equal(sheet[4 : 4 + 8 * DEFAULT_SIZE, 4 : 4 + 8 * DEFAULT_SIZE], first)  # seed 0 in the top-left tile


def test_worlds_command_bad_count_is_one_line(tmp_path):
    result = runner.invoke(app, ["worlds", "harvest", "--n", "0", "--out", str(tmp_path / "x.png")])
    assert result.exit_code == 2
    assert "error:" in result.output and len(result.output.strip().splitlines()) == 1
    assert not (tmp_path / "x.png").exists()


def test_draw_episodes_tints_the_cells_each_agent_visited(generated_maps):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from worldagent.agents.loaders import load_agent
    from worldagent.envs import registry
    from worldagent.evaluation.trajectories import replay, scored_keys

    spec = registry.get("harvest")
    env, params = spec.make_env()
    world = index_maps(generated_maps, 0)
    episodes = replay(spec, env, load_agent(spec, "random"), world, scored_keys(3, 2), params, num_steps=20)
    counts = render.visit_counts(episodes, (25, 25))
    assert counts.shape == (4, 25, 25)
    np.testing.assert_array_equal(counts.sum(axis=(1, 2)), episodes.present.sum(axis=(0, 1)))  # one count per agent-step on the map
    figure, axis = plt.subplots()
    render.draw_episodes(axis, world, episodes)
    assert len(axis.images) == 2 and axis.get_legend() is not None
    plt.close(figure)


def test_reach_tints_only_where_the_tagger_can_walk():
    world = HarvestMap.from_str(
        """
        ..#....
        ..#....
        ###....
        .......
        ......A
        """
    )
    plain, tinted = (np.asarray(render.draw_map(world, cell=2, agents=False, reach=reach)) for reach in (False, True))
    inside, outside, apple = tinted[2, 2], tinted[8, 10], tinted[8, 12]  # cell (1, 1), (4, 5), (4, 6)
    assert tuple(inside) == render.REACH and tuple(outside) == render.BACKGROUND and tuple(apple) == render.APPLE
    np.testing.assert_array_equal(tinted[4:, 6:], plain[4:, 6:])  # beyond the walls nothing changes
