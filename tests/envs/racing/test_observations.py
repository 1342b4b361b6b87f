"""Racing's observations without a route: the road around the agent ("surroundings", "rays"), its shape, what it sees, jit and vmap."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from worldagent.agents.algorithms import training_config
from worldagent.envs import registry
from worldagent.envs.racing.env import RAY_DIRECTIONS, ParticleRacing, RacingParams, road_here, road_pixels, road_rays
from worldagent.envs.racing.tracks import rasterize
from worldagent.envs.racing.world import RASTER_SIZE, ROAD_SIZE, Track, pack_road, to_pixel, unpack_road
from worldagent.errors import WorldagentError

PARAMS = RacingParams()
KEY = jax.random.key(0)
SURROUNDINGS = ParticleRacing(observation="surroundings", window=16, reach=64, coarse=16)
RAYS = ParticleRacing(observation="rays", reach=64)


@pytest.fixture(scope="module")
def oval():
    """An ellipse 0.6 × 0.4, point 0 at its east end, driven counter-clockwise."""
    theta = np.linspace(0.0, 2 * np.pi, 256, endpoint=False)
    centreline = np.stack([0.6 * np.cos(theta), 0.4 * np.sin(theta)], axis=-1).astype(np.float32)
    return Track(centreline, rasterize(centreline, RASTER_SIZE), pack_road(rasterize(centreline, ROAD_SIZE)))


def first(tracks, i=0):
    return jax.tree_util.tree_map(lambda x: x[i], tracks)


@pytest.mark.parametrize("env, size", [(SURROUNDINGS, 16 * 16 + 16 * 16 + 4), (RAYS, RAY_DIRECTIONS + 10)])
def test_observation_shape_and_no_route(track, env, size):
    obs, state = env.reset(KEY, track, PARAMS)
    assert obs.shape == env.observation_shape == (size,) and obs.dtype == jnp.float32
    np.testing.assert_allclose(obs[-4:-2], track.centreline[0])  # position, then velocity (at rest)
    np.testing.assert_array_equal(obs[-2:], 0.0)
    _, moved = env.place(state, np.asarray(track.centreline[40]), [0.0, 0.0], PARAMS)
    assert moved.segment != state.segment
    far = np.asarray(track.centreline[40]) + np.array([0.0, 0.0])
    _, same_place = env.place(state, far, [0.0, 0.0], PARAMS)
    np.testing.assert_array_equal(env.observe(moved, PARAMS), env.observe(same_place, PARAMS))  # a function of where it is, not of the route


def test_road_pixels_is_the_unpacked_mask_with_grass_beyond_it(tracks):
    world = first(tracks, 3)
    road = np.pad(unpack_road(world.road), 40)  # off the mask is grass
    for position in [*np.asarray(world.centreline[::37]), np.array([0.98, -0.97], np.float32)]:
        row, col = np.round(to_pixel(position, ROAD_SIZE)).astype(int) - 32 + 40
        np.testing.assert_array_equal(road_pixels(world.road, jnp.asarray(position), 64), road[row : row + 64, col : col + 64])


def test_surroundings_see_the_road(track):
    """On the centreline the fine window's centre is road and the coarse view has road; on the grass neither."""
    _, state = SURROUNDINGS.reset(KEY, track, PARAMS)
    on_road = np.asarray(SURROUNDINGS.observe(state, PARAMS))
    grass = np.asarray(SURROUNDINGS.observe(state.replace(position=jnp.array([0.95, 0.95])), PARAMS))  # a corner of the field
    fine, coarse = on_road[:256].reshape(16, 16), on_road[256:512].reshape(16, 16)
    assert fine[7:9, 7:9].all() and 0 < fine.mean() < 0.5
    assert 0 < coarse.mean() < 0.5 and coarse.max() <= 1.0
    assert not grass[:256].any()
    assert not np.array_equal(on_road[:512], grass[:512])


def test_rays_measure_the_road_ahead_on_a_straight(track):
    """On the start straight (heading north) the north and south rays run far; the east and west ones end at the kerb."""
    _, state = RAYS.reset(KEY, track, PARAMS)
    rays = np.asarray(road_rays(state.world.road, state.position, 32))
    east, north, west, south = (rays[i * RAY_DIRECTIONS // 4] for i in range(4))
    assert north > 0.2 and south > 0.2
    assert east < 0.1 and west < 0.1
    assert np.all((rays >= 0) & (rays <= 1))
    off = np.asarray(road_rays(state.world.road, jnp.array([0.95, 0.95]), 32))
    np.testing.assert_array_equal(off, 0.0)  # on the grass no ray starts on the road


def test_road_here_is_the_nearest_centre_and_the_axis_either_way(oval):
    """Off the middle of the road the offset points back to it; the axis is the same driven either way."""
    _, state = RAYS.reset(KEY, oval, PARAMS)
    centre, axis = road_here(oval.centreline, state.segment, state.position + jnp.array([0.01, 0.0]))  # east end, road runs north
    np.testing.assert_allclose(centre, [-0.01, 0.0], atol=1e-4)
    np.testing.assert_allclose(axis, [-1.0, 0.0], atol=0.05)  # θ ≈ 90°: (cos 180°, sin 180°)
    backwards = oval.centreline[::-1]
    np.testing.assert_allclose(road_here(backwards, 254, backwards[254])[1], axis, atol=0.05)


@pytest.mark.parametrize("env", [SURROUNDINGS, RAYS], ids=["surroundings", "rays"])
def test_observations_equal_under_jit_and_vmap(tracks, env):
    worlds = jax.tree_util.tree_map(lambda x: x[:4], tracks)
    positions = jnp.asarray(np.asarray(worlds.centreline[:, 17]) + 0.005)
    velocities = jnp.full((4, 2), 0.01)

    def observe(world, position, velocity):
        _, state = env.reset(KEY, world, PARAMS)
        return env.observe(state.replace(position=position, velocity=velocity), PARAMS)

    eager = np.stack([observe(first(worlds, i), positions[i], velocities[i]) for i in range(4)])
    np.testing.assert_array_equal(jax.jit(jax.vmap(observe))(worlds, positions, velocities), eager)
    np.testing.assert_array_equal(jax.jit(observe)(first(worlds, 1), positions[1], velocities[1]), eager[1])


def test_the_observation_picks_the_training_settings_that_made_it_lap():
    for algo in ("ppo", "acktr"):
        route, rays = (training_config("racing", algo, options={"observation": obs}) for obs in ("route", "rays"))
        assert route == training_config("racing", algo) and not route.quadratic and route.crash_warmup == 0.0
        assert rays.quadratic and rays.crash_warmup == 0.5
        assert training_config("racing", algo, options={"observation": "rays"}, crash_warmup=0.0).crash_warmup == 0.0  # overrides win
    acktr = training_config("racing", "acktr", options={"observation": "rays"})
    assert (acktr.learning_rate, acktr.kl_clip) == (1.0, 0.003) and training_config("racing", "acktr").kl_clip == 0.01


def test_spec_option_picks_the_observation():
    spec = registry.get("racing")
    assert spec.make_env()[0].observation == "route"
    env, params = spec.make_env(spec.parse_options(["observation=surroundings", "reach=96", "respawn_speed=0.5"]))
    assert env.observation == "surroundings" and env.reach == 96 and env.window == 16 and params.respawn_speed == 0.5
    assert spec.make_env({"observation": "rays"})[0].observation_shape == (RAY_DIRECTIONS + 10,)
    # without the route a respawned agent restarts moving (at rest it learnt to park), unless told otherwise
    assert spec.make_env()[1].respawn_speed == 0.0 and spec.make_env({"observation": "rays"})[1].respawn_speed == 0.5
    assert spec.make_env({"observation": "rays", "respawn_speed": 0.0})[1].respawn_speed == 0.0
    with pytest.raises(WorldagentError, match="fraction"):
        spec.parse_options(["respawn_speed=2"])
    with pytest.raises(WorldagentError, match="observation"):
        spec.parse_options(["observation=pixels"])
    with pytest.raises(WorldagentError, match="multiple of 16"):
        spec.parse_options(["reach=50"])
    with pytest.raises(WorldagentError, match="reach a multiple of coarse"):
        ParticleRacing(observation="surroundings", window=16, reach=50, coarse=16)
    with pytest.raises(WorldagentError, match="observation="):
        ParticleRacing(observation="pixels")


def test_respawn_speed_restarts_along_the_road_in_the_driving_direction(oval):
    """At the east end of the oval the road runs north; a respawn there restarts northwards at the given speed."""
    env = RAYS
    params = PARAMS.replace(respawn=True, respawn_speed=0.5)
    _, state = env.reset(KEY, oval, params)
    _, state = env.place(state, [0.6, 0.0], [0.05, 0.0], params)  # about to leave the road eastwards
    _, after, reward, terminated, _, info = env.step(KEY, state, 0, params)
    assert bool(info["crashed"]) and not bool(terminated) and float(reward) < -290
    top = params.force / params.friction
    np.testing.assert_allclose(np.linalg.norm(after.velocity), 0.5 * top, rtol=1e-5)
    assert after.velocity[1] > 0.99 * 0.5 * top  # northwards: the way the oval is driven


def test_rays_heading_is_the_unit_velocity_once_moving(track):
    """The heading (before position and velocity) has unit length at any speed above the floor and is 0 at rest."""
    obs, state = RAYS.reset(KEY, track, PARAMS)
    np.testing.assert_array_equal(obs[-6:-4], 0.0)
    for speed in (0.004, 0.04):  # one push, the top speed
        _, moving = RAYS.place(state, np.asarray(track.centreline[0]), [0.0, speed], PARAMS)
        np.testing.assert_allclose(RAYS.observe(moving, PARAMS)[-6:-4], [0.0, 1.0], atol=1e-6)


def test_a_kept_heading_faces_the_start_line_and_survives_a_stop(oval):
    """heading="kept": along the start line at reset; the last motion's direction while (nearly) at rest, where the
    unit velocity ("motion") shrinks to a tenth and points back the way the last push went."""
    kept = ParticleRacing(observation="rays", heading="kept")
    obs, state = kept.reset(KEY, oval, PARAMS)
    np.testing.assert_allclose(obs[-6:-4], [0.0, 1.0], atol=0.05)  # the oval is driven north from its east end
    east, west = 0, 1  # ACTION_NAMES
    _, state, *_ = kept.step(KEY, state, east, PARAMS)
    _, state, *_ = kept.step(KEY, state, west, PARAMS)  # 0.9 · 0.004 − 0.004: nearly at rest, drifting west
    np.testing.assert_allclose(kept.observe(state, PARAMS)[-6:-4], [1.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(RAYS.observe(state, PARAMS)[-6:-4], [-0.2, 0.0], atol=1e-5)
    with pytest.raises(WorldagentError, match="heading"):
        ParticleRacing(observation="rays", heading="compass")
    assert registry.get("racing").make_env({"observation": "rays", "heading": "kept"})[0].heading == "kept"
