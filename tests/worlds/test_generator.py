"""G(z): pure, jittable, vmappable; clear errors at its boundary; quality figures; save/load."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from worldagent.errors import WorldagentError
from worldagent.worlds.generator import build_generator, load_generator, save_generator
from worldagent.worlds.quality import harvest_figures, racing_figures


@pytest.mark.parametrize("which", ["racing", "harvest"])
def test_generator_runs_under_jit_and_vmap(which, request):
    generator = request.getfixturevalue(f"{which}_generator")
    z = jax.random.normal(jax.random.key(0), (6, generator.latent_dim))
    eager = generator(z)
    jitted = jax.jit(lambda g, z: g(z))(generator, z)
    mapped = jax.jit(jax.vmap(lambda g, z: g(z[None]), in_axes=(None, 0)))(generator, z)
    for name in vars(eager):
        np.testing.assert_array_equal(getattr(eager, name), getattr(jitted, name))
        np.testing.assert_array_equal(np.asarray(getattr(mapped, name))[:, 0], getattr(eager, name))


def test_racing_generator_returns_dataset_tracks(racing_generator, racing_data):
    z = jax.random.normal(jax.random.key(3), (8, racing_generator.latent_dim))
    index = np.asarray(racing_generator.track_indices(z))
    tracks = racing_generator(z)
    np.testing.assert_array_equal(np.asarray(tracks.centreline), racing_data.worlds.centreline[index])
    np.testing.assert_array_equal(np.asarray(tracks.road), racing_data.worlds.road[index])


def test_harvest_generator_maps_are_valid_with_the_median_apple_count(harvest_generator, harvest_data):
    maps = harvest_generator(jax.random.normal(jax.random.key(4), (32, harvest_generator.latent_dim)))
    counts = np.asarray(maps.apples).reshape(32, -1).sum(1)
    median = int(np.median(harvest_data.worlds.apples.reshape(len(harvest_data), -1).sum(1)))
    assert (counts == median).all() and harvest_generator.apples == median
    maps.validate()


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_latents_get_a_clear_error(racing_generator, harvest_generator, bad):
    for generator in (racing_generator, harvest_generator):
        z = np.zeros((3, generator.latent_dim), np.float32)
        z[1, 4] = bad
        with pytest.raises(WorldagentError, match="latents contains NaN or infinite"):
            generator(z)


def test_wrongly_shaped_latents_get_a_clear_error(racing_generator):
    for shape in [(10,), (4, 3), (2, 2, 10)]:
        with pytest.raises(WorldagentError, match="latents have shape"):
            racing_generator(jnp.zeros(shape))


def test_a_generator_needs_the_vaes_own_dataset(racing_vae, harvest_data):
    with pytest.raises(WorldagentError, match="pass the dataset it was trained on"):
        build_generator(racing_vae, harvest_data)


def test_save_and_load_give_the_same_generator(tmp_path, racing_vae, racing_data, racing_generator):
    dataset_path = racing_data.save(tmp_path / "data.npz")
    save_generator(tmp_path / "g", racing_vae, dataset_path, racing_generator)
    loaded, _, _ = load_generator(tmp_path / "g")
    z = jax.random.normal(jax.random.key(5), (8, racing_generator.latent_dim))
    np.testing.assert_array_equal(loaded.track_indices(z), racing_generator.track_indices(z))
    with pytest.raises(WorldagentError, match="holds no generator"):
        load_generator(tmp_path / "elsewhere")


def test_quality_figures_at_small_scale(racing_generator, racing_data, harvest_generator):
    racing = racing_figures(racing_generator, racing_data, 500, jax.random.key(0))
    assert 0.0 <= racing["self_mapping_rate"] <= 1.0
    assert racing["self_mapping_rate"] > 5 / len(racing_data)  # far above chance
    assert 1 < racing["coverage_distinct_tracks"] <= len(racing_data)
    harvest = harvest_figures(harvest_generator, 200, jax.random.key(0))
    assert harvest["validity_after_repair"] == 1.0
    assert 0.0 <= harvest["validity_before_repair"] <= 1.0
    assert harvest["distinct_wall_layouts"] >= 1
