import jax
import jax.numpy as jnp
import numpy as np
import pytest

from worldagent.agents.distributions import LatentWorlds, WorldPool, check_weights, world_distribution
from worldagent.errors import WorldagentError
from worldagent.worlds.dataset import make_dataset


def test_pool_samples_per_weights(racing_pool):
    weights = np.array([4.0, 0.0, 2.0, 1.0, 1.0, 0.0, 0.0, 0.0])
    pool = WorldPool.create(racing_pool.worlds, weights)
    n = 40_000
    index = np.asarray(jax.jit(jax.vmap(pool.sample_index))(jax.random.split(jax.random.key(0), n)))
    freq = np.bincount(index, minlength=8) / n
    expected = weights / weights.sum()
    assert np.all(freq[expected == 0] == 0)
    # 5 sigma of a binomial proportion
    assert np.all(np.abs(freq - expected) <= 5 * np.sqrt(expected * (1 - expected) / n) + 1e-12)


def test_pool_sample_is_one_world_and_matches_index(racing_pool):
    key = jax.random.key(3)
    world = jax.jit(racing_pool.sample)(key)
    index = int(racing_pool.sample_index(key))
    assert world.centreline.shape == (256, 2)
    np.testing.assert_array_equal(world.road, racing_pool.worlds.road[index])
    batch = racing_pool.sample_batch(jax.random.key(1), 5)
    assert batch.centreline.shape == (5, 256, 2)


def test_uniform_by_default(racing_pool):
    np.testing.assert_allclose(racing_pool.probs, np.full(8, 1 / 8), rtol=1e-6)


@pytest.mark.parametrize(
    "weights, message",
    [
        ([1.0, np.nan, 1, 1, 1, 1, 1, 1], "NaN"),
        ([1.0, -1, 1, 1, 1, 1, 1, 1], "negative"),
        (np.zeros(8), "all zero"),
        (np.ones(3), "shape"),
    ],
)
def test_bad_weights_refused(racing_pool, weights, message):
    with pytest.raises(WorldagentError, match=message):
        WorldPool.create(racing_pool.worlds, weights)


def test_check_weights_normalises():
    np.testing.assert_allclose(check_weights([1, 3], 2), [0.25, 0.75])


def test_dataset_file_spec_and_wrong_env(tmp_path):
    path = make_dataset("harvest", 4, 0, progress=False).save(tmp_path / "harvest.npz")
    with pytest.raises(WorldagentError, match="holds harvest worlds, not racing"):
        world_distribution("racing", str(path))
    pool = world_distribution("harvest", str(path), weights=[1, 0, 0, 0])
    assert pool.size == 4 and float(pool.probs[0]) == 1.0


def test_bad_specs_refused(tmp_path):
    with pytest.raises(WorldagentError, match="unknown world distribution"):
        world_distribution("racing", "procedural")
    with pytest.raises(WorldagentError, match="generator directory"):
        world_distribution("racing", "vae")
    with pytest.raises(WorldagentError, match="does not exist"):
        world_distribution("racing", str(tmp_path / "missing.npz"))
    with pytest.raises(WorldagentError, match="unknown environment"):
        world_distribution("chess", "generator")
    with pytest.raises(WorldagentError, match="at least 1"):
        world_distribution("racing", "generator", size=0)


def test_latent_worlds_decode_to_dataset_tracks(racing_pool):
    from worldagent.envs.repairs import NearestWorld
    from worldagent.worlds.generator import Generator
    from worldagent.worlds.vae import VAE

    model = VAE(cell_count=64 * 64, latent_dim=10, encoder=(8,), decoder=(8,))
    params = model.init(jax.random.key(0), jnp.zeros((1, 64 * 64)), jax.random.key(1))["params"]
    rasters = jnp.asarray(racing_pool.worlds.raster.reshape(8, -1), jnp.float32)
    generator = Generator(params, NearestWorld(rasters, racing_pool.worlds), model, "racing", (64, 64))
    dist = LatentWorlds(generator)
    world = jax.jit(dist.sample)(jax.random.key(0))
    assert world.centreline.shape == (256, 2)
    matches = np.all(np.asarray(racing_pool.worlds.centreline) == np.asarray(world.centreline), axis=(1, 2))
    assert matches.sum() >= 1
    assert dist.sample_batch(jax.random.key(1), 3).road.shape == (3, 128, 4)
