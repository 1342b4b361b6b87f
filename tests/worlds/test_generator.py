"""G(z): pure, jittable, vmappable; clear errors at its boundary; quality figures; save/load."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import worldagent.worlds.generator as generator_module
from worldagent.envs import registry
from worldagent.envs.harvest.repair import HarvestRepair, mean_apples
from worldagent.envs.harvest.world import DEFAULT_SIZE, index_maps
from worldagent.envs.repairs import NearestWorld
from worldagent.errors import WorldagentError
from worldagent.worlds.generator import FIT_SEED, build_generator, fit_repair, load_generator, save_generator
from worldagent.worlds.quality import figures

BATCH = 32  # every eager harvest decode here: one shape, so JAX compiles each eager op once for the file


@pytest.mark.integration
@pytest.mark.parametrize("which", ["racing", "harvest"])
def test_generator_runs_under_jit_and_vmap(which, request):
    generator = request.getfixturevalue(f"{which}_generator")
    z = jax.random.normal(jax.random.key(0), (BATCH, generator.latent_dim))
    eager = generator(z)
    jitted = jax.jit(lambda g, z: g(z))(generator, z)
    mapped = jax.jit(jax.vmap(lambda g, z: g(z[None]), in_axes=(None, 0)))(generator, z)
    for name in vars(eager):
        np.testing.assert_array_equal(getattr(eager, name), getattr(jitted, name))
        np.testing.assert_array_equal(np.asarray(getattr(mapped, name))[:, 0], getattr(eager, name))


def test_generator_is_repair_of_the_decoded_logits(harvest_generator):
    z = jax.random.normal(jax.random.key(2), (BATCH, harvest_generator.latent_dim))
    direct = harvest_generator.repair(harvest_generator.logits(z))
    for name in vars(direct):
        np.testing.assert_array_equal(getattr(harvest_generator(z), name), getattr(direct, name))
    assert harvest_generator.env == "harvest" and harvest_generator.cell_shape == (2, DEFAULT_SIZE, DEFAULT_SIZE)


def test_racing_generator_returns_dataset_tracks(racing_generator, racing_data):
    """G picks behind the decoder's last layer (``folded``) the very tracks the repair picks from the logits."""
    assert isinstance(racing_generator.repair, NearestWorld) and racing_generator.folded is not None
    z = 2 * jax.random.normal(jax.random.key(3), (64, racing_generator.latent_dim))
    index = np.asarray(racing_generator.repair.indices(racing_generator.logits(z)))
    tracks = racing_generator(z)
    np.testing.assert_array_equal(np.asarray(tracks.centreline), racing_data.worlds.centreline[index])
    np.testing.assert_array_equal(np.asarray(tracks.road), racing_data.worlds.road[index])


def test_harvest_generator_maps_are_valid_with_the_median_apple_count(harvest_generator, harvest_data):
    assert isinstance(harvest_generator.repair, HarvestRepair)
    maps = harvest_generator(jax.random.normal(jax.random.key(4), (BATCH, harvest_generator.latent_dim)))
    counts = np.asarray(maps.apples).reshape(BATCH, -1).sum(1)
    median = int(np.median(harvest_data.worlds.apples.reshape(len(harvest_data), -1).sum(1)))
    assert (counts == median).all() and harvest_generator.repair.config == {"apples": median, "walls": "nearest"}
    maps.validate()
    layouts = {row.tobytes() for row in harvest_data.worlds.walls.reshape(len(harvest_data), -1)}
    assert all(row.tobytes() in layouts for row in np.asarray(maps.walls).reshape(BATCH, -1))  # walls snap to the dataset's rooms


def test_repair_config_sets_the_apple_count_and_is_checked(harvest_vae, harvest_data):
    generator = build_generator(harvest_vae, harvest_data, repair_config={"apples": 7})
    maps = generator(jnp.zeros((BATCH, generator.latent_dim)))
    assert (np.asarray(maps.apples).reshape(BATCH, -1).sum(1) == 7).all()
    for bad in (-1, DEFAULT_SIZE * DEFAULT_SIZE):
        with pytest.raises(WorldagentError, match="apples="):
            build_generator(harvest_vae, harvest_data, repair_config={"apples": bad})


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
    meta = json.loads((tmp_path / "g" / "generator.json").read_text())
    assert meta["env"] == "racing" and meta["repair"] == {} and meta["fingerprint"] == racing_data.fingerprint
    loaded, _, _ = load_generator(tmp_path / "g")
    z = jax.random.normal(jax.random.key(5), (8, racing_generator.latent_dim))
    np.testing.assert_array_equal(loaded.repair.indices(loaded.logits(z)), racing_generator.repair.indices(racing_generator.logits(z)))
    with pytest.raises(WorldagentError, match="holds no generator"):
        load_generator(tmp_path / "elsewhere")


def test_the_repair_config_survives_save_and_load_and_old_files_load(tmp_path, harvest_vae, harvest_data):
    dataset_path = harvest_data.save(tmp_path / "data.npz")
    save_generator(tmp_path / "g", harvest_vae, dataset_path, build_generator(harvest_vae, harvest_data, repair_config={"apples": 9}))
    assert load_generator(tmp_path / "g")[0].repair.config == {"apples": 9, "walls": "nearest"}
    meta = json.loads((tmp_path / "g" / "generator.json").read_text())
    del meta["repair"]
    median = build_generator(harvest_vae, harvest_data).repair.apples
    for apples, expected in ((11, 11), (0, median)):  # old files recorded "apples": K, or 0 for the default
        (tmp_path / "g" / "generator.json").write_text(json.dumps({**meta, "apples": apples}))
        assert load_generator(tmp_path / "g")[0].repair.config == {"apples": expected, "walls": "nearest"}


def test_a_fitted_repair_is_fitted_once_recorded_and_decodes_the_same_after_loading(tmp_path, harvest_vae, harvest_data, monkeypatch):
    monkeypatch.setattr(generator_module, "FIT_LATENTS", 64)  # a quarter of the decodes: the same code, a quarter of the time
    unfitted = build_generator(harvest_vae, harvest_data, repair_config={"apples": "spread"})
    generator = fit_repair(unfitted, harvest_data)
    shift = generator.repair.config["apple_shift"]
    assert unfitted.repair.config["apple_shift"] is None and isinstance(shift, float)
    assert fit_repair(generator, harvest_data) is generator  # fitted once: a saved shift is kept
    save_generator(tmp_path / "g", harvest_vae, harvest_data.save(tmp_path / "data.npz"), generator)
    loaded = load_generator(tmp_path / "g")[0]
    assert loaded.repair.config == generator.repair.config
    apples = jax.jit(lambda g, z: g(z).apples)  # both generators share its one compile: same shapes, same settings
    prior = jax.random.normal(jax.random.key(FIT_SEED), (64, generator.latent_dim))  # the decodes it was fitted on
    fitted_apples = np.asarray(apples(generator, prior))
    np.testing.assert_array_equal(np.asarray(apples(loaded, prior)), fitted_apples)
    counts = fitted_apples.sum(axis=(1, 2))
    target = mean_apples(harvest_data.worlds)
    assert abs(counts.mean() - target) <= 0.05 * target  # the dataset's mean count
    top_k = build_generator(harvest_vae, harvest_data)
    assert fit_repair(top_k, harvest_data) is top_k  # the paper's top-K apples fit nothing


@pytest.mark.integration
def test_quality_figures_at_small_scale(racing_generator, racing_data, harvest_generator, harvest_data):
    racing = figures(racing_generator, racing_data, 500, jax.random.key(0))
    assert racing["self_mapping_rate"] > 5 / len(racing_data)  # far above chance
    assert 1 < racing["coverage_distinct_worlds"] == racing["distinct_layouts"] <= len(racing_data)
    assert racing["coverage_fraction"] == racing["coverage_distinct_worlds"] / len(racing_data)  # racing only returns dataset worlds
    assert racing["validity_after_repair"] == 1.0 and "validity_before_repair" not in racing  # racing has no raw decode
    assert 1 / 500 <= racing["most_reached_share"] <= 1.0 and racing["samples"] == 500
    harvest = figures(harvest_generator, harvest_data, 200, jax.random.key(0))
    assert harvest["validity_after_repair"] == 1.0
    assert 0.0 <= harvest["validity_before_repair"] <= 1.0
    assert 0.0 <= harvest["self_mapping_rate"] <= 1.0
    assert harvest["distinct_layouts"] >= 1 and harvest["mean_cell_hamming"] >= 0.0
    assert 0.0 <= harvest["coverage_fraction"] <= 1.0
    separated = harvest["structure"]["tagger_separated"]
    describe = registry.get("harvest").metrics.descriptors["tagger_separated"]
    assert separated["dataset"] == pytest.approx(np.mean([describe(index_maps(harvest_data.worlds, i)) for i in range(len(harvest_data))]))
    assert 0.0 <= separated["generator"] <= 1.0 and set(harvest["structure"]) == set(registry.get("harvest").metrics.descriptors)
    assert set(racing["structure"]) == {"total_curvature", "sharpest_corner", "track_length"}
    with pytest.raises(WorldagentError, match="at least 1"):
        figures(harvest_generator, harvest_data, 0, jax.random.key(0))


def test_self_mapping_agrees_with_the_nearest_world_indices(racing_generator, racing_data):
    """By cells, a world maps back to itself when the repair picks it (or an identical duplicate)."""
    from worldagent.worlds.quality import _self_mapping_rate

    subset = racing_data.subset(np.arange(64))
    own = np.asarray(racing_generator.repair.indices(racing_generator.logits(racing_generator.encode(subset.cells))))
    rate = _self_mapping_rate(racing_generator, subset, registry.get("racing"))
    assert rate >= np.mean(own == np.arange(64)) and rate * 64 == pytest.approx(round(rate * 64))


def test_a_named_repair_is_recorded_and_loaded_by_name(tmp_path, racing_vae, racing_data):
    open_generator = build_generator(racing_vae, racing_data, repair_name="open")
    z = jax.random.normal(jax.random.key(7), (6, open_generator.latent_dim))
    decode = jax.jit(lambda g, z: g(z))  # one compile for both generators (eager, the walker's many small ops each compile)
    tracks = decode(open_generator, z)
    tracks.validate()
    dataset = {row.tobytes() for row in racing_data.cells}
    assert not any(row.tobytes() in dataset for row in registry.get("racing").cells(tracks))  # open: none is a dataset track
    save_generator(tmp_path / "g", racing_vae, racing_data.save(tmp_path / "data.npz"), open_generator)
    assert json.loads((tmp_path / "g" / "generator.json").read_text())["repair_name"] == "open"
    loaded = load_generator(tmp_path / "g")[0]
    assert loaded.repair_name == "open"
    np.testing.assert_array_equal(decode(loaded, z).raster, tracks.raster)
    assert build_generator(racing_vae, racing_data).repair_name == "nearest"  # the paper's stays the default


def test_an_unknown_repair_name_lists_the_known_ones(racing_vae, racing_data):
    with pytest.raises(WorldagentError, match="no repair 'closest'; use one of: nearest, open"):
        build_generator(racing_vae, racing_data, repair_name="closest")
