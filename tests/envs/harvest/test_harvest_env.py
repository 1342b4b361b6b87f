"""Resource Harvest dynamics: moves, harvesting, regrowth, TAG, observations, jit/vmap, errors."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from worldagent.envs.core import step_autoreset
from worldagent.envs.harvest.env import (
    BACKWARD,
    DISC_OFFSETS,
    FORWARD,
    LEFT,
    NOOP,
    RIGHT,
    ROTATE_LEFT,
    ROTATE_RIGHT,
    TAG,
    Harvest,
    make_params,
    perolat_regrowth_table,
    shift_sum,
)
from worldagent.envs.harvest.policies import random_act
from worldagent.envs.harvest.world import DEFAULT_SIZE, HarvestMap, index_maps
from worldagent.errors import WorldagentError

N, E, S, W = range(4)
FAR = [[0, 0], [0, 8], [8, 0], [8, 8]]  # the corners of the 9x9 open map


def actions(**by_agent):
    """int32[4] NOOPs except the named agents, e.g. actions(a0=FORWARD)."""
    out = [NOOP] * 4
    for name, action in by_agent.items():
        out[int(name[1:])] = action
    return jnp.array(out, jnp.int32)


def rollout_states(env, step_fn, key, state, params, num_steps):
    """States after each of ``num_steps`` random-action steps, stacked on a leading axis."""

    def one(state, step_key):
        key_act, key_env = jax.random.split(step_key)
        obs = env.observe(state, params)
        _, state, reward, *_ = env.step(key_env, state, random_act(None, obs, key_act), params)
        return state, (state.replace(world=None), reward)

    return jax.lax.scan(one, state, jax.random.split(key, num_steps))


def test_reset_puts_agents_at_their_corners(env, reset_fn, generated_maps):
    world = index_maps(generated_maps, 0)
    obs, state = reset_fn(jax.random.key(0), world, env.default_params)
    assert obs.shape == (4, 15, 15, 4) and obs.dtype == jnp.uint8
    last = DEFAULT_SIZE - 1
    assert state.position.tolist() == [[0, 0], [0, last], [last, 0], [last, last]]
    assert state.heading.tolist() == [S, S, N, N]
    np.testing.assert_array_equal(state.apples, world.apples)


@pytest.mark.parametrize(
    "heading, action, moved_to, new_heading",
    [
        (N, FORWARD, (3, 4), N),
        (N, BACKWARD, (5, 4), N),
        (N, LEFT, (4, 3), N),
        (N, RIGHT, (4, 5), N),
        (E, FORWARD, (4, 5), E),
        (E, LEFT, (3, 4), E),
        (S, RIGHT, (4, 3), S),
        (W, BACKWARD, (4, 5), W),
        (N, ROTATE_LEFT, (4, 4), W),
        (N, ROTATE_RIGHT, (4, 4), E),
        (W, ROTATE_RIGHT, (4, 4), N),
    ],
)
def test_moves_and_rotations_are_relative_to_the_heading(place, step_fn, open_map, quiet_params, heading, action, moved_to, new_heading):
    state = place(open_map, quiet_params, position=[[4, 4], *FAR[1:]], heading=[heading, S, N, N])
    _, state, *_ = step_fn(jax.random.key(1), state, actions(a0=action), quiet_params)
    assert tuple(state.position[0].tolist()) == moved_to
    assert int(state.heading[0]) == new_heading


def test_walls_grid_edges_and_agents_block_moves(place, step_fn, quiet_params):
    world = HarvestMap.from_str(
        """
        .....
        ..#..
        .....
        .....
        .....
        """
    )
    # agent 0 below the wall facing it; agent 1 at the top edge facing out; agent 2 walks into agent 3
    state = place(world, quiet_params, position=[[2, 2], [0, 4], [4, 2], [4, 3]], heading=[N, N, E, N])
    _, state, *_ = step_fn(jax.random.key(2), state, jnp.array([FORWARD, FORWARD, FORWARD, NOOP]), quiet_params)
    assert state.position.tolist() == [[2, 2], [0, 4], [4, 2], [4, 3]]


def test_an_apple_is_harvested_once_for_plus_one(place, step_fn, open_map, quiet_params):
    apples = np.zeros((9, 9), bool)
    apples[3, 4] = True
    world = open_map.replace(apples=apples)
    state = place(world, quiet_params, position=[[4, 4], *FAR[1:]], heading=[N, S, N, N])
    _, state, reward, *_ = step_fn(jax.random.key(3), state, actions(a0=FORWARD), quiet_params)
    assert reward.tolist() == [1.0, 0.0, 0.0, 0.0]
    assert not state.apples.any()
    for i, move in enumerate([BACKWARD, FORWARD, NOOP]):
        _, state, reward, *_ = step_fn(jax.random.key(4 + i), state, actions(a0=move), quiet_params)
        assert reward.tolist() == [0.0] * 4
    assert state.returns.tolist() == [1.0, 0.0, 0.0, 0.0]


def test_simultaneous_claims_are_fair_and_key_determined(env, place, open_map, quiet_params):
    apples = np.zeros((9, 9), bool)
    apples[4, 4] = True
    state = place(open_map.replace(apples=apples), quiet_params, position=[[4, 3], [4, 5], [8, 0], [8, 8]], heading=[E, W, N, N])
    both = jnp.array([FORWARD, FORWARD, NOOP, NOOP])
    batch_step = jax.jit(jax.vmap(lambda k: env.step(k, state, both, quiet_params)[1:3]))
    keys = jax.random.split(jax.random.key(5), 400)
    states, rewards = batch_step(keys)
    at_centre = (states.position == jnp.array([4, 4])).all(-1)  # [400, 4]
    assert (at_centre.sum(axis=1) == 1).all()  # exactly one winner, the loser stays put
    assert (rewards.sum(axis=1) == 1).all()  # the apple is harvested once
    wins = int(at_centre[:, 0].sum())
    assert 140 < wins < 260  # 200 expected, sd 10
    again, _ = batch_step(keys)
    np.testing.assert_array_equal(again.position, states.position)


def test_neighbour_count_is_apples_within_euclidean_radius_two():
    grid = np.random.default_rng(0).random((9, 11)) < 0.4
    count = np.asarray(shift_sum(jnp.asarray(grid), DISC_OFFSETS))
    rows, cols = np.nonzero(np.ones_like(grid))
    for r, c in zip(rows, cols):
        near = [(rr, cc) for rr in range(9) for cc in range(11) if 0 < (rr - r) ** 2 + (cc - c) ** 2 <= 4]
        assert count[r, c] == sum(grid[p] for p in near)
    assert len(DISC_OFFSETS) == 12


def test_regrowth_frequency_matches_the_table(env, place, quiet_params):
    """Empirical regrowth of one empty site with L apples around it, for L = 0..12."""
    table = perolat_regrowth_table()
    assert table[[0, 1, 2, 3, 4, 5, 12]].tolist() == pytest.approx([0, 0.01, 0.01, 0.05, 0.05, 0.1, 0.1])
    params = make_params()
    sites = np.zeros((9, 9), bool)
    sites[4, 4] = True
    for dr, dc in DISC_OFFSETS:
        sites[4 + dr, 4 + dc] = True
    world = HarvestMap(walls=np.zeros((9, 9), bool), apples=sites)

    def start(count):  # the centre empty, the first ``count`` neighbours holding apples
        apples = np.zeros((9, 9), bool)
        for dr, dc in DISC_OFFSETS[:count]:
            apples[4 + dr, 4 + dc] = True
        return place(world, params, apples=apples)

    starts = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *[start(count) for count in range(13)])
    draws = 20000
    regrew = jax.jit(
        jax.vmap(
            lambda s: jax.vmap(lambda k: env.step(k, s, jnp.zeros(4, jnp.int32), params)[1].apples[4, 4])(jax.random.split(jax.random.key(7), draws))
        )
    )(starts)
    frequency = np.asarray(regrew).mean(axis=1)
    sd = np.sqrt(table * (1 - table) / draws)
    assert frequency[0] == 0.0
    np.testing.assert_array_less(np.abs(frequency - table), 5 * sd + 1e-9)


def test_regrowth_only_on_apple_sites_and_never_under_agents(env, place, step_fn, generated_maps):
    always = make_params(regrowth_probability=np.ones(13))  # regrow everywhere it may, at once
    world = index_maps(generated_maps, 3)
    _, state = jax.jit(env.reset)(jax.random.key(0), world, always)
    _, (states, _) = jax.jit(lambda s: rollout_states(env, step_fn, jax.random.key(8), s, always, 200))(state)
    apples = np.asarray(states.apples)
    assert not (apples & ~world.apples[None]).any()
    on_map = np.asarray(states.tagged_timer) == 0
    rows, cols = np.asarray(states.position[..., 0]), np.asarray(states.position[..., 1])
    steps = np.arange(200)[:, None]
    assert not (apples[steps, rows, cols] & on_map).any()
    # An agent standing on a harvested site keeps it empty; when it leaves the apple returns.
    site = np.zeros((9, 9), bool)
    site[4, 4] = True
    state = place(HarvestMap(walls=np.zeros((9, 9), bool), apples=site), always, position=[[4, 4], *FAR[1:]], apples=np.zeros((9, 9), bool))
    for _ in range(3):
        _, state, *_ = step_fn(jax.random.key(9), state, actions(), always)
        assert not state.apples[4, 4]
    _, state, *_ = step_fn(jax.random.key(10), state, actions(a0=FORWARD), always)
    assert state.apples[4, 4]


def tag_scene(place, world, params, target):
    """Agent 0 at (1, 4) facing south; agent 1 at ``target``; the others in far corners."""
    return place(world, params, position=[[1, 4], target, [8, 0], [8, 8]], heading=[S, N, N, N])


@pytest.mark.parametrize(
    "target, hit",
    [
        ((2, 4), True),
        ((6, 4), True),
        ((7, 4), False),
        ((4, 3), True),
        ((4, 5), True),
        ((4, 2), False),
        ((4, 6), False),
        ((1, 5), False),
        ((0, 4), False),
    ],
)
def test_tag_beam_is_three_wide_and_five_long(place, step_fn, open_map, tag_params, target, hit):
    state = tag_scene(place, open_map, tag_params, target)
    _, state, _, _, _, info = step_fn(jax.random.key(11), state, actions(a0=TAG), tag_params)
    assert info["hit"].tolist() == [False, hit, False, False]
    assert bool(state.tagged_timer[1] == 25) == hit


def test_tag_is_refused_where_the_mask_disables_it(place, step_fn, open_map, quiet_params, tag_params):
    state = tag_scene(place, open_map, quiet_params, (3, 4))
    _, after, *_, info = step_fn(jax.random.key(12), state, actions(a0=TAG), quiet_params)
    assert not info["hit"].any() and after.position.tolist() == state.position.tolist()
    # agent 1 may not tag even where agent 0 may
    state = place(open_map, tag_params, position=[[4, 4], [2, 4], [8, 0], [8, 8]], heading=[N, S, N, N])
    _, _, *_, info = step_fn(jax.random.key(13), state, actions(a1=TAG), tag_params)
    assert not info["hit"].any()


def test_walls_stop_the_beam_lane_by_lane(place, step_fn, tag_params):
    world = HarvestMap.from_str("\n".join(["........."] * 3 + ["....#...."] + ["........."] * 5))
    state = place(world, tag_params, position=[[1, 4], [5, 4], [5, 5], [8, 8]], heading=[S, N, N, N])
    _, _, *_, info = step_fn(jax.random.key(14), state, actions(a0=TAG), tag_params)
    assert info["hit"].tolist() == [False, False, True, False]


def test_a_tagged_agent_is_out_for_exactly_25_steps(env, place, step_fn, open_map, tag_params):
    state = tag_scene(place, open_map, tag_params, (4, 4))
    obs, state, *_ = step_fn(jax.random.key(15), state, actions(a0=TAG), tag_params)
    out = []
    for t in range(30):
        assert bool(obs[1, ..., 3].all()) == bool(state.tagged_timer[1] > 0)  # the tagged-out plane
        out.append(bool(state.tagged_timer[1] > 0))
        if out[-1]:
            assert not obs[1, ..., :3].any()
        obs, state, *_ = step_fn(jax.random.key(16 + t), state, actions(a1=FORWARD), tag_params)
    assert out[:25] == [True] * 25 and out[25:] == [False] * 5
    assert state.times_tagged.tolist() == [0, 1, 0, 0]
    assert state.conflict_steps == 25 and state.untagged_agent_steps == 31 * 4 - 25
    # back at its corner (0, 8) facing south, then it walked forward for the remaining steps
    assert state.position[1].tolist() == [5, 8]
    metrics = env.metrics(state)
    assert float(metrics["conflict"]) == pytest.approx(25 / 31)
    assert float(metrics["peace"]) == pytest.approx((31 * 4 - 25) / 31)


def test_an_out_agent_waits_while_its_corner_is_taken(place, step_fn, open_map):
    params = make_params(can_tag=[True, False, False, False], tag_out_steps=1, regrowth_probability=np.zeros(13))
    state = place(open_map, params, position=[[1, 4], [2, 4], [0, 8], [8, 8]], heading=[S, N, N, N])
    _, state, *_ = step_fn(jax.random.key(17), state, actions(a0=TAG), params)  # hits agent 1 (agent 2 is beside, not ahead)
    assert state.tagged_timer.tolist() == [0, 1, 0, 0]
    _, state, *_ = step_fn(jax.random.key(18), state, actions(), params)  # agent 2 sits on agent 1's corner
    assert state.tagged_timer.tolist() == [0, 1, 0, 0]
    _, state, *_ = step_fn(jax.random.key(19), state, actions(a2=BACKWARD), params)  # it steps away
    assert state.tagged_timer.tolist() == [0, 0, 0, 0] and state.position[1].tolist() == [0, 8]


@pytest.mark.parametrize("heading", [N, E, S, W])
def test_observation_is_rotated_to_the_heading(env, place, open_map, quiet_params, heading):
    world = HarvestMap.from_str("\n".join(["." * 25] * 25))
    forward = np.array([[-1, 0], [0, 1], [1, 0], [0, -1]])[heading]
    right = np.array([[-1, 0], [0, 1], [1, 0], [0, -1]])[(heading + 1) % 4]
    walls, apples = np.zeros((25, 25), bool), np.zeros((25, 25), bool)
    walls[tuple(np.array([12, 12]) + 3 * forward + right)] = True
    apples[tuple(np.array([12, 12]) - 2 * forward - 2 * right)] = True
    world = HarvestMap(walls=walls, apples=apples)
    state = place(world, quiet_params, position=[[12, 12], [12, 14], [0, 24], [24, 0]], heading=[heading, N, N, N])
    obs = np.asarray(env.observe(state, quiet_params))[0]
    me_row, me_col = 15 - 1 - env.view_behind, 15 // 2
    assert np.argwhere(obs[..., 0]).tolist() == [[me_row - 3, me_col + 1]]
    assert np.argwhere(obs[..., 1]).tolist() == [[me_row + 2, me_col - 2]]
    other = np.array([12, 14]) - np.array([12, 12])  # agent 1, two cells east
    ahead, rightward = int(other @ forward), int(other @ right)
    assert np.argwhere(obs[..., 2]).tolist() == [[me_row - ahead, me_col + rightward]]
    assert not obs[..., 3].any()


def test_outside_the_grid_reads_as_wall(env, reset_fn, open_map, quiet_params):
    obs, _ = reset_fn(jax.random.key(0), open_map, quiet_params)
    # agent 0 at (0, 0) faces south: behind it (north) and on its right (west) lies the outside
    me_row, me_col = 15 - 1 - env.view_behind, 15 // 2
    assert obs[0, me_row + 1, me_col, 0] == 1  # behind: row -1
    assert obs[0, me_row, me_col + 1, 0] == 1  # its right when facing south is west: col -1
    assert obs[0, me_row - 1, me_col, 0] == 0  # ahead is open


def test_same_key_same_episode(env, reset_fn, step_fn, generated_maps):
    params = make_params(can_tag=[True, False, False, False])
    _, state = reset_fn(jax.random.key(0), index_maps(generated_maps, 5), params)
    run = jax.jit(lambda k: rollout_states(env, step_fn, k, state, params, 100))
    first, second, other = run(jax.random.key(20)), run(jax.random.key(20)), run(jax.random.key(21))
    for a, b in zip(jax.tree_util.tree_leaves(first), jax.tree_util.tree_leaves(second)):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(first[0].position, other[0].position)


def test_runs_under_jit_and_vmap_over_different_maps(env, step_fn, generated_maps):
    params = env.default_params
    worlds = index_maps(generated_maps, slice(0, 8))
    keys = jax.random.split(jax.random.key(22), 8)
    obs, states = jax.jit(jax.vmap(env.reset, in_axes=(0, 0, None)))(keys, worlds, params)
    assert obs.shape == (8, 4, 15, 15, 4)
    action = jnp.tile(jnp.array([FORWARD, RIGHT, LEFT, FORWARD]), (8, 1))
    batched = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
    obs, states_after, reward, terminated, truncated, _ = batched(keys, states, action, params)
    assert reward.shape == (8, 4) and truncated.shape == (8, 4)
    one = jax.tree_util.tree_map(lambda x: x[3], states)
    single_obs, single, *_ = step_fn(keys[3], one, action[3], params)
    np.testing.assert_array_equal(obs[3], single_obs)
    np.testing.assert_array_equal(states_after.apples[3], single.apples)
    np.testing.assert_array_equal(states_after.position[3], single.position)


def test_episode_truncates_and_autoresets(env, reset_fn, open_map):
    params = make_params(max_steps=3)
    _, state = reset_fn(jax.random.key(0), open_map, params)
    auto = jax.jit(lambda k, s, a: step_autoreset(env, k, s, a, params))
    truncations = []
    for t in range(4):
        _, state, _, terminated, truncated, _ = auto(jax.random.key(30 + t), state, actions(a0=FORWARD))
        truncations.append(bool(truncated.all()))
        assert not terminated.any()
    assert truncations == [False, False, True, False]
    assert int(state.time) == 1 and state.position[0].tolist() == [1, 0]


def test_bad_input_is_a_one_line_error(env, open_map):
    with pytest.raises(WorldagentError, match="exactly 4 agents"):
        Harvest(num_agents=3)
    with pytest.raises(WorldagentError, match="shape"):
        env.check_action([0, 1, 2])
    with pytest.raises(WorldagentError, match=r"\[0, 8\)"):
        env.check_action([0, 1, 2, 8])
    with pytest.raises(WorldagentError, match="spawn corner"):
        env.check_world(HarvestMap.from_str("#..\n...\n..."))
    with pytest.raises(WorldagentError, match="one map"):
        env.check_world(HarvestMap(walls=np.zeros((2, 5, 5), bool), apples=np.zeros((2, 5, 5), bool)))
    with pytest.raises(WorldagentError, match="can_tag"):
        make_params(can_tag=[True])
    with pytest.raises(WorldagentError, match="13 probabilities"):
        make_params(regrowth_probability=[0.1, 0.2])
    with pytest.raises(WorldagentError, match="odd"):
        Harvest(view_size=14)
    env.check_action(np.array([0, 7, 3, 1]))
    env.check_world(open_map)


def test_options_set_the_window_the_beam_and_regrowth():
    from worldagent.envs import registry
    from worldagent.envs.harvest.env import perolat_regrowth_table
    from worldagent.errors import WorldagentError

    spec = registry.get("harvest")
    env, params = spec.make_env(spec.parse_options(["tagger=0", "view_size=21", "view_behind=0", "beam_length=7", "regrowth=0.5"]))
    assert (env.view_size, env.view_behind, env.beam_length) == (21, 0, 7) and env.observation_shape == (21, 21, 4)
    np.testing.assert_allclose(params.regrowth_probability, 0.5 * perolat_regrowth_table())
    assert params.can_tag.tolist() == [True, False, False, False]
    _, dense = spec.make_env({"regrowth": 20.0})
    assert float(dense.regrowth_probability.max()) == 1.0  # probabilities are capped
    for bad in ("view_size=0", "view_behind=-1", "regrowth=-0.5", "beam_length=x"):
        with pytest.raises(WorldagentError, match=bad.split("=")[0]):
            spec.parse_options([bad])
