"""The vectorised Gymnasium env (``make_vec``), its world sources, and the single env's pooled resets."""

from __future__ import annotations

import time

import gymnasium
import jax
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode, VectorEnv

import worldagent  # noqa: F401  (registers worldagent/ParticleRacing-v0 and its vector entry point)
from worldagent.envs import vector
from worldagent.envs.adapters import ParticleRacingGym
from worldagent.envs.racing.env import ParticleRacing, RacingParams
from worldagent.envs.vector import ParticleRacingVectorEnv, track_pool
from worldagent.errors import WorldagentError
from worldagent.worlds.dataset import make_dataset
from worldagent.worlds.generator import build_generator, save_generator
from worldagent.worlds.vae import VAEConfig, train_vae

NUM_ENVS = 8
POOL_SIZE = 4  # ~0.1 s to generate
SHORT = RacingParams(max_steps=3)  # every episode ends within 3 steps


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """A cache folder of this module's own, so no test writes into the user's home."""
    return tmp_path_factory.mktemp("cache")


def make_envs(cache, num_envs=NUM_ENVS, **kwargs) -> VectorEnv:
    return gymnasium.make_vec("worldagent/ParticleRacing-v0", num_envs=num_envs, pool_size=POOL_SIZE, cache_dir=cache, **kwargs)


@pytest.fixture(scope="module")
def tiny_generator(tmp_path_factory):
    """(G, its dataset, a generator directory): a one-epoch VAE on 8 tracks; G maps every z to one of them."""
    dataset = make_dataset("racing", 8, 0, progress=False)
    vae = train_vae(dataset, VAEConfig(latent_dim=2, encoder=(16,), decoder=(16,), epochs=1, batch_size=4, warmup_epochs=0), progress=False)
    generator = build_generator(vae, dataset)
    folder = tmp_path_factory.mktemp("generator")
    save_generator(folder / "g", vae, dataset.save(folder / "tracks.npz"), generator)
    return generator, dataset, folder


def world_indices(centrelines, dataset_centrelines) -> np.ndarray:
    """int[N]: which dataset track each world is (every world must be one of them)."""
    same = (np.asarray(centrelines)[:, None] == np.asarray(dataset_centrelines)[None]).all(axis=(2, 3))
    assert same.any(axis=1).all(), "a world is not one of the source's"
    return same.argmax(axis=1)


def test_make_vec_returns_a_same_step_vector_env_with_batched_spaces(cache):
    envs = make_envs(cache)
    assert isinstance(envs, VectorEnv) and isinstance(envs.unwrapped, ParticleRacingVectorEnv)
    assert envs.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP and envs.num_envs == NUM_ENVS
    single_shape = ParticleRacing().observation_shape
    assert envs.single_observation_space.shape == single_shape and envs.observation_space.shape == (NUM_ENVS, *single_shape)
    assert envs.single_action_space == gymnasium.spaces.Discrete(4)
    assert envs.action_space == gymnasium.spaces.MultiDiscrete([4] * NUM_ENVS)
    obs, info = envs.reset(seed=0)
    assert obs.shape == (NUM_ENVS, *single_shape) and obs.dtype == np.float32 and info == {}
    assert envs.observation_space.contains(obs)


def test_random_actions_step_every_env_and_return_numpy(cache):
    envs = make_envs(cache)
    envs.reset(seed=1)
    envs.action_space.seed(1)
    for _ in range(20):
        obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
        assert envs.observation_space.contains(obs)
        for array, dtype in ((reward, np.float32), (terminated, np.bool_), (truncated, np.bool_)):
            assert isinstance(array, np.ndarray) and array.shape == (NUM_ENVS,) and array.dtype == dtype
        assert np.isfinite(reward).all() and not (terminated & truncated).any()
        assert {"crashed", "lap_completed", "progress"} <= set(info) and info["progress"].shape == (NUM_ENVS,)
    obs[:] = 0.0  # the arrays are the caller's to modify


def test_an_ended_episode_restarts_on_a_newly_drawn_world_in_the_same_step(cache):
    envs = make_envs(cache, params=SHORT)
    pool = track_pool(POOL_SIZE, 0, cache).worlds
    envs.reset(seed=2)
    seen = [world_indices(envs.unwrapped.worlds.centreline, pool.centreline)]
    actions = np.zeros(NUM_ENVS, np.int64)
    for _episode in range(4):
        for _ in range(3):
            before = np.asarray(envs.unwrapped.worlds.centreline)
            obs, reward, terminated, truncated, info = envs.step(actions)
        done = terminated | truncated
        assert done.all() and info["_final_obs"].all() and info["_final_info"].all()
        np.testing.assert_array_equal(info["final_info"]["steps"], 3)
        assert not np.array_equal(info["final_obs"], obs)
        # The returned observation is the new episode's first: the start line of the new world.
        worlds = envs.unwrapped.worlds
        fresh, _ = jax.vmap(ParticleRacing().reset, in_axes=(None, 0, None))(jax.random.key(0), worlds, SHORT)
        np.testing.assert_allclose(obs, np.asarray(fresh), atol=1e-6)
        seen.append(world_indices(worlds.centreline, pool.centreline))
        assert not np.array_equal(np.asarray(worlds.centreline), before)
    # Each episode's world is drawn anew: over 5 episodes every env met several pool tracks.
    assert all(len(set(history)) > 1 for history in np.stack(seen).T)


def test_the_same_seed_gives_the_same_observations(cache):
    actions = np.random.default_rng(0).integers(0, 4, (12, NUM_ENVS))

    def rollout(seed):
        envs = make_envs(cache, params=SHORT)
        observations = [envs.reset(seed=seed)[0]]
        observations += [envs.step(action)[0] for action in actions]
        return np.stack(observations)

    first = rollout(5)
    np.testing.assert_array_equal(first, rollout(5))
    assert not np.array_equal(first, rollout(6))


def test_generator_worlds_are_drawn_inside_the_step_one_z_per_episode(tiny_generator, cache):
    generator, dataset, folder = tiny_generator
    for source in (generator, folder / "g"):
        envs = make_envs(cache, num_envs=3, generator=source, params=SHORT)
        envs.reset(seed=0)
        seen = [world_indices(envs.unwrapped.worlds.centreline, dataset.worlds.centreline)]
        for _ in range(9):  # three episodes each: the stock of 3 worlds is refilled twice
            _, _, terminated, truncated, _ = envs.step(np.zeros(3, np.int64))
            seen.append(world_indices(envs.unwrapped.worlds.centreline, dataset.worlds.centreline))
        assert (terminated | truncated).all()
        assert len(set(np.concatenate(seen).tolist())) > 1  # new z, new worlds (G is barely trained: few distinct ones)
    with pytest.raises(WorldagentError, match="either pool= or generator="):
        make_envs(cache, generator=generator, pool=folder / "tracks.npz")


def test_a_dataset_file_can_be_the_pool(tiny_generator, cache):
    _, dataset, folder = tiny_generator
    envs = make_envs(cache, pool=folder / "tracks.npz", params=SHORT)
    envs.reset(seed=0)
    for _ in range(6):
        envs.step(np.ones(NUM_ENVS, np.int64))
        world_indices(envs.unwrapped.worlds.centreline, dataset.worlds.centreline)


def test_vector_env_contract_by_hand(cache):
    """What ``check_env`` checks for a single env, for the vector env: spaces, seeding, types, errors."""
    envs = make_envs(cache, params=SHORT)
    with pytest.raises(RuntimeError, match="reset"):
        envs.step(np.zeros(NUM_ENVS, np.int64))
    obs, _ = envs.reset(seed=0)
    again, _ = envs.reset(seed=0)
    np.testing.assert_array_equal(obs, again)
    obs, *_ = envs.step(envs.action_space.sample())
    assert envs.observation_space.contains(obs)
    for bad in (np.zeros(NUM_ENVS - 1, np.int64), np.full(NUM_ENVS, 4), np.full(NUM_ENVS, 0.5)):
        with pytest.raises(WorldagentError, match="action"):
            envs.step(bad)
    with pytest.raises(ValueError, match="seed"):
        envs.reset(seed=[0, 1])
    with pytest.raises(ValueError, match="options"):
        envs.reset(options={"reset_mask": np.ones(NUM_ENVS, bool)})
    for kwargs, message in (({"num_envs": 0}, "num_envs"), ({"pool_size": 0}, "pool_size"), ({"params": {"max_steps": 3}}, "RacingParams")):
        with pytest.raises(WorldagentError, match=message):
            ParticleRacingVectorEnv(**{"num_envs": 2, "cache_dir": cache, **kwargs})
    envs.close()


def test_episode_statistics_wrapper_counts_same_step_episodes(cache):
    envs = gymnasium.wrappers.vector.RecordEpisodeStatistics(make_envs(cache, params=SHORT))
    envs.reset(seed=0)
    for _ in range(6):
        *_, info = envs.step(np.zeros(NUM_ENVS, np.int64))
    np.testing.assert_array_equal(info["episode"]["l"], 3)
    np.testing.assert_allclose(info["episode"]["r"], info["final_info"]["return"], rtol=1e-5)


def test_the_pool_is_generated_once_cached_on_disk_and_remade_if_corrupted(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    pool = track_pool(2, 100)
    path = tmp_path / "worldagent" / "racing-pool-2-seed100.npz"
    assert path.is_file() and list(pool.seeds) == [100, 101]
    assert track_pool(2, 100) is pool  # in memory after the first call
    path.write_bytes(b"not a zip file")
    vector._cached_pool.cache_clear()  # as in a new process
    remade = track_pool(2, 100)
    np.testing.assert_array_equal(remade.worlds.centreline, pool.worlds.centreline)
    with pytest.raises(WorldagentError, match="pool_seed"):
        track_pool(2, -1)


def test_single_env_resets_from_the_pool_in_well_under_two_milliseconds(cache):
    env = gymnasium.make("worldagent/ParticleRacing-v0", pool_size=POOL_SIZE, cache_dir=cache).unwrapped
    assert isinstance(env, ParticleRacingGym)
    check_env(env)
    seeds = {env.reset()[1]["track_seed"] for _ in range(40)}
    assert seeds == set(range(POOL_SIZE))
    start = time.perf_counter()
    for _ in range(50):
        env.reset()
    assert (time.perf_counter() - start) / 50 < 0.02  # 2 ms on an idle machine; loose against CI noise
    _, info = env.reset(options={"track_seed": 11})
    assert info["track_seed"] == 11
