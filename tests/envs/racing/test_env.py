"""Particle Racing dynamics: rewards, crash / lap / truncation boundaries, jit and vmap."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from worldagent.envs.core import rollout, step_autoreset
from worldagent.envs.racing.driver import DriverParams, driver_action
from worldagent.envs.racing.env import ROUTE_SCALE, ParticleRacing, RacingParams, episode_metrics, locate, split_observation, wrap_half
from worldagent.envs.racing.tracks import rasterize
from worldagent.envs.racing.world import HALF_WIDTH, RASTER_SIZE, ROAD_SIZE, Track, pack_road, to_pixel, unpack_road
from worldagent.envs.registry import ScriptedPolicy
from worldagent.errors import WorldagentError

ENV = ParticleRacing()
PARAMS = RacingParams()
EAST = 0
KEY = jax.random.key(0)
step = jax.jit(ENV.step)
DRIVER = ScriptedPolicy((PARAMS, DriverParams()), lambda params, obs, key, state: driver_action(state, *params), privileged=True)
drive = jax.jit(lambda key, world: rollout(ENV, DRIVER, key, world, PARAMS, 300))


def oval_track(a: float = 0.6, b: float = 0.4, num_points: int = 256) -> Track:
    """An analytic ellipse, point 0 at its east end (a, 0), driven counter-clockwise."""
    theta = np.linspace(0.0, 2 * np.pi, num_points, endpoint=False)
    centreline = np.stack([a * np.cos(theta), b * np.sin(theta)], axis=-1).astype(np.float32)
    return Track(centreline, rasterize(centreline, RASTER_SIZE), pack_road(rasterize(centreline, ROAD_SIZE)))


@pytest.fixture(scope="module")
def oval():
    return oval_track()


RANDOM = ScriptedPolicy(None, lambda params, obs, key, state: jax.random.randint(key, (), 0, ENV.num_actions))


def arrive_at(env, state, target, action=EAST):
    """Place the agent at point 0 with the velocity that lands it on ``target`` after ``action``."""
    origin = np.asarray(state.world.centreline[0], np.float64)
    force = PARAMS.force * np.eye(2)[0] if action == EAST else None
    velocity = (np.asarray(target) - origin - force) / (1.0 - PARAMS.friction)
    return env.place(state, origin.astype(np.float32), velocity.astype(np.float32), PARAMS)[1]


@pytest.mark.parametrize("offset, crashes", [(HALF_WIDTH - 2e-3, False), (HALF_WIDTH + 2e-3, True)])
def test_crash_exactly_when_leaving_the_road(oval, offset, crashes):
    _, state = ENV.reset(KEY, oval, PARAMS)
    state = arrive_at(ENV, state, (0.6 + offset, 0.0))
    _, after, reward, terminated, truncated, info = step(KEY, state, EAST, PARAMS)
    assert bool(after.crashed) == crashes == bool(terminated) == bool(info["crashed"])
    assert not bool(truncated)
    expected = -PARAMS.step_penalty + PARAMS.lap_reward * float(wrap_half(after.arc - state.arc)) - 300.0 * crashes
    assert float(reward) == pytest.approx(expected, abs=1e-4)


def test_reward_is_step_penalty_plus_progress(tracks):
    world = jax.tree_util.tree_map(lambda x: x[3], tracks)
    final, trajectory = drive(KEY, world)
    alive = np.asarray(trajectory["alive"])
    progress = np.concatenate([[0.0], np.asarray(trajectory["state"].progress)[alive]])
    rewards = np.asarray(trajectory["reward"])[alive]
    np.testing.assert_allclose(rewards, -0.2 + 100.0 * np.diff(progress), atol=1e-3)
    assert float(final.episode_return) == pytest.approx(rewards.sum(), abs=1e-2)


def test_lap_completes_at_the_first_step_with_a_full_lap_of_progress(oval):
    final, trajectory = drive(KEY, oval)
    alive = np.asarray(trajectory["alive"])
    progress = np.asarray(trajectory["state"].progress)[alive]
    lap = np.asarray(trajectory["state"].lap_completed)[alive]
    assert bool(final.lap_completed) and not bool(final.crashed)
    first_full = int(np.argmax(progress >= 1.0))
    assert progress[first_full] >= 1.0 and np.all(progress[:first_full] < 1.0)
    assert lap[first_full] and not lap[:first_full].any()
    assert len(progress) == first_full + 1  # the episode ended on that step
    assert int(final.time) == first_full + 1 < PARAMS.max_steps


def test_truncation_exactly_at_max_steps(oval):
    _, state = ENV.reset(KEY, oval, PARAMS)
    state = state.replace(time=jnp.int32(PARAMS.max_steps - 2))
    _, state, _, terminated, truncated, _ = step(KEY, state, 2, PARAMS)  # north: along the road at point 0
    assert not bool(terminated) and not bool(truncated)
    _, state, _, terminated, truncated, _ = step(KEY, state, 2, PARAMS)
    assert bool(truncated) and not bool(terminated) and int(state.time) == PARAMS.max_steps


def test_a_crash_on_the_last_step_is_termination_not_truncation(oval):
    _, state = ENV.reset(KEY, oval, PARAMS)
    state = arrive_at(ENV, state, (0.6 + HALF_WIDTH + 1e-2, 0.0)).replace(time=jnp.int32(PARAMS.max_steps - 1))
    _, _, _, terminated, truncated, _ = step(KEY, state, EAST, PARAMS)
    assert bool(terminated) and not bool(truncated)


def test_same_seed_same_episode_and_different_seed_different_episode(track):
    run = jax.jit(lambda k, w: rollout(ENV, RANDOM, k, w, PARAMS, 300))
    (first, traj_a), (second, traj_b), (_, traj_c) = run(KEY, track), run(KEY, track), run(jax.random.key(1), track)
    np.testing.assert_array_equal(traj_a["state"].position, traj_b["state"].position)
    assert float(first.episode_return) == float(second.episode_return)
    assert not np.array_equal(traj_a["action"], traj_c["action"])


def test_jit_vmap_over_different_worlds_matches_one_by_one(tracks):
    keys = jax.random.split(KEY, 8)
    run = lambda k, w: episode_metrics(rollout(ENV, RANDOM, k, w, PARAMS, 60)[0])  # noqa: E731
    batched = jax.jit(jax.vmap(run))(keys, tracks)
    run_one = jax.jit(run)
    for i in range(8):
        single = run_one(keys[i], jax.tree_util.tree_map(lambda x: x[i], tracks))
        for name in single:
            np.testing.assert_allclose(batched[name][i], single[name], rtol=1e-5)
    assert len(np.unique(np.asarray(batched["return"]))) > 1


def test_reference_driver_laps_most_tracks():
    from worldagent.envs.racing.tracks import generate_tracks

    worlds = generate_tracks(np.arange(100, 132))
    run = jax.jit(jax.vmap(lambda k, w: episode_metrics(rollout(ENV, DRIVER, k, w, PARAMS, 300)[0])))
    metrics = run(jax.random.split(KEY, 32), worlds)
    assert float(np.mean(metrics["lap_completed"])) >= 0.9
    assert float(np.mean(metrics["crashed"])) <= 0.1


def test_local_segment_search_agrees_with_the_whole_loop(tracks):
    """The ±search_radius search finds the true nearest segment along real drives."""
    for i in (0, 5):
        world = jax.tree_util.tree_map(lambda x: x[i], tracks)
        _, trajectory = drive(KEY, world)
        positions = np.asarray(trajectory["state"].position)[np.asarray(trajectory["alive"])]
        c = np.asarray(world.centreline, np.float64)
        d = np.roll(c, -1, axis=0) - c
        t = np.clip(np.einsum("tkd,kd->tk", positions[:, None] - c[None], d) / (d * d).sum(-1), 0, 1)
        exact = np.linalg.norm(positions[:, None] - (c[None] + t[..., None] * d[None]), axis=-1).min(axis=1)
        local = jax.vmap(lambda p, s: locate(world.centreline, p, s, ENV.search_radius)[2])(
            positions, np.asarray(trajectory["state"].segment)[np.asarray(trajectory["alive"])]
        )
        np.testing.assert_allclose(local, exact, atol=1e-5)


WINDOWED = ParticleRacing(window=16)


def test_observation_window_shows_the_road_around_the_agent(track):
    obs, state = WINDOWED.reset(KEY, track, PARAMS)
    assert obs.shape == WINDOWED.observation_shape == (16 * 16 + 4 + 2 * len(WINDOWED.route),)
    window, position, velocity, _ = split_observation(np.asarray(obs), WINDOWED.window)
    assert window.shape == (16, 16)
    assert window[7:9, 7:9].any()
    assert 0 < window.mean() < 1  # both road and grass in view
    np.testing.assert_allclose(position, track.centreline[0])
    np.testing.assert_array_equal(velocity, 0.0)


def test_route_sensor_shows_the_centreline_ahead_relative_to_the_agent(track):
    obs, state = ENV.reset(KEY, track, PARAMS)
    assert obs.shape == ENV.observation_shape == (4 + 2 * len(ENV.route),)
    _, position, _, route = split_observation(np.asarray(obs), ENV.window)
    expected = (np.asarray(track.centreline)[list(ENV.route)] - position) / ROUTE_SCALE
    np.testing.assert_allclose(route, expected, rtol=1e-5, atol=1e-6)
    middle = (np.asarray(track.centreline[10]) + np.asarray(track.centreline[11])) / 2  # on segment 10
    _, moved = ENV.place(state, middle, [0.0, 0.0], PARAMS)  # the route moves with the agent
    route_later = split_observation(np.asarray(ENV.observe(moved, PARAMS)), 0)[3]
    np.testing.assert_allclose(route_later[0] * ROUTE_SCALE, track.centreline[10 + ENV.route[0]] - middle, atol=1e-6)


def test_respawn_puts_a_crashed_agent_back_on_the_track_and_carries_on(oval):
    respawning = PARAMS.replace(respawn=True)
    _, state = ENV.reset(KEY, oval, respawning)
    state = arrive_at(ENV, state, (0.6 + HALF_WIDTH + 1e-2, 0.0))
    progress_before = float(state.progress)
    _, after, reward, terminated, truncated, info = step(KEY, state, EAST, respawning)
    assert bool(info["crashed"]) and float(reward) < -290  # the paper's penalty is still paid
    assert not bool(terminated) and not bool(truncated) and not bool(after.done)
    assert bool(after.crashed)  # recorded for the episode's crash rate
    np.testing.assert_allclose(after.position, oval.centreline[int(after.segment)])
    np.testing.assert_array_equal(after.velocity, 0.0)
    assert abs(float(after.progress) - progress_before) < 2.0 / oval.centreline.shape[0]  # no progress from respawning
    _, crashed, _, ended, _, _ = step(KEY, state, EAST, PARAMS)  # without respawn the same crash ends it
    assert bool(ended) and bool(crashed.done)


def test_autoreset_restarts_on_the_same_world_after_a_crash(oval):
    _, state = ENV.reset(KEY, oval, PARAMS)
    state = arrive_at(ENV, state, (0.6 + HALF_WIDTH + 1e-2, 0.0))
    obs, after, reward, terminated, _, _ = jax.jit(lambda k, s, a: step_autoreset(ENV, k, s, a, PARAMS))(KEY, state, EAST)
    assert bool(terminated) and float(reward) < -290
    assert int(after.time) == 0 and not bool(after.crashed)
    np.testing.assert_allclose(after.position, oval.centreline[0])
    np.testing.assert_array_equal(after.world.road, oval.road)
    np.testing.assert_array_equal(obs, ENV.reset(KEY, oval, PARAMS)[0])


def test_bad_inputs_get_one_line_errors(track, oval):
    bad_shape = Track(np.zeros((100, 2), np.float32), track.raster, track.road)
    with pytest.raises(WorldagentError, match="centreline has shape"):
        ENV.reset(KEY, bad_shape, PARAMS)
    nan_world = Track(np.where(np.arange(256)[:, None] == 3, np.nan, track.centreline).astype(np.float32), track.raster, track.road)
    with pytest.raises(WorldagentError, match="NaN"):
        ENV.reset(KEY, nan_world, PARAMS)
    too_big = Track(track.centreline * 1.3, track.raster, track.road)
    with pytest.raises(WorldagentError, match="playable square"):
        ENV.reset(KEY, too_big, PARAMS)
    _, state = ENV.reset(KEY, oval, PARAMS)
    with pytest.raises(WorldagentError, match="position contains NaN"):
        ENV.place(state, [np.nan, 0.0], [0.0, 0.0], PARAMS)
    with pytest.raises(WorldagentError, match="velocity has shape"):
        ENV.place(state, [0.6, 0.0], [0.0, 0.0, 0.0], PARAMS)
    for action in (4, -1, 1.5):
        with pytest.raises(WorldagentError, match="valid action"):
            ENV.step(KEY, state, action, PARAMS)
    with pytest.raises(WorldagentError, match="window"):
        ParticleRacing(window=64)
    with pytest.raises(WorldagentError, match="route"):
        ParticleRacing(route=(0, 3))
    for message in ("centreline has shape", "valid action"):  # one line each, naming the fix
        try:
            ENV.reset(KEY, bad_shape, PARAMS) if "shape" in message else ENV.step(KEY, state, 9, PARAMS)
        except WorldagentError as error:
            assert "\n" not in str(error)


def test_observation_window_is_the_unpacked_road_around_the_agent(tracks):
    """The bit-packed window equals a plain slice of the unpacked mask, at every column phase."""
    world = jax.tree_util.tree_map(lambda x: x[2], tracks)
    road = unpack_road(world.road)
    _, state = WINDOWED.reset(KEY, world, PARAMS)
    observe = jax.jit(WINDOWED.observe)
    size = WINDOWED.window
    for position in np.asarray(world.centreline[::7]):
        obs = observe(state.replace(position=jnp.asarray(position)), PARAMS)
        window = split_observation(np.asarray(obs), size)[0]
        row, col = np.round(to_pixel(position, ROAD_SIZE)).astype(int) - size // 2
        np.testing.assert_array_equal(window, road[row : row + size, col : col + size])


def test_pack_road_round_trips(track):
    mask = unpack_road(track.road)
    assert mask.shape == (ROAD_SIZE, ROAD_SIZE) and mask.any()
    np.testing.assert_array_equal(pack_road(mask), track.road)


def test_autoreset_onto_a_new_world_when_one_is_given(oval, track):
    _, state = ENV.reset(KEY, oval, PARAMS)
    crash = arrive_at(ENV, state, (0.6 + HALF_WIDTH + 1e-2, 0.0))
    auto = jax.jit(lambda k, s, a, w: step_autoreset(ENV, k, s, a, PARAMS, next_world=w))
    _, after, _, terminated, _, _ = auto(KEY, crash, EAST, track)
    assert bool(terminated)
    np.testing.assert_array_equal(after.world.centreline, track.centreline)
    np.testing.assert_allclose(after.position, track.centreline[0])
    _, going_on, _, terminated, _, _ = auto(KEY, state, 2, track)  # no episode end: same world
    assert not bool(terminated)
    np.testing.assert_array_equal(going_on.world.centreline, oval.centreline)
