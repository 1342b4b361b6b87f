"""Generator quality that cannot fail silently (issue 39): latent use, sensitivity, spread, warnings.

The stranger's case: 13x13 mazes of 0-25 scattered walls (tests/scatter_env.py), on which a plain
VAE learnt the mean maze. With the default free bits the generator keeps using z; a generator
collapsed on purpose, or one whose repair throws the decoded walls away, is told so in one line.
"""

from __future__ import annotations

from dataclasses import replace

import jax
import numpy as np
import pytest

from scatter_env import registered
from worldagent.worlds.dataset import make_dataset
from worldagent.worlds.generator import build_generator
from worldagent.worlds.quality import diagnose, figures, latent_usage, reconstruction, sensitivity, spread
from worldagent.worlds.vae import split_holdout, train_vae

DECODES = 1000


@pytest.fixture(scope="module")
def scatter_data():
    with registered():
        yield make_dataset("scatter", 512, 0, progress=False)


def measure(generator, data, config):
    """(reconstruction, figures over 1,000 draws, warnings) of a scatter generator."""
    train, held = split_holdout(len(data), config.holdout, config.seed)
    recon = reconstruction(generator, data, held, train)
    measured = figures(generator, data, DECODES, jax.random.key(0))
    return recon, measured, diagnose(recon, measured, len(data))


@pytest.fixture(scope="module")
def default_scatter(scatter_data, small_vae):
    """A small VAE with the default training settings (free bits among them) and the count-keeping repair."""
    vae = train_vae(scatter_data, small_vae, progress=False)
    with registered():
        yield vae, *measure(build_generator(vae, scatter_data), scatter_data, small_vae)


def test_free_bits_keep_a_scattered_walls_generator_in_use(default_scatter, small_vae):
    assert small_vae.free_bits > 0  # the defaults under test
    vae, recon, measured, warnings = default_scatter
    latent = measured["latent"]
    assert latent["active_units"] >= 3 and len(latent["kl_per_dim"]) == vae.config.latent_dim
    assert latent["kl_total"] == pytest.approx(sum(latent["kl_per_dim"]))
    assert measured["coverage_distinct_worlds"] >= 900 and measured["distinct_share"] == measured["coverage_distinct_worlds"] / DECODES
    walls = measured["structure"]["wall_count"]
    assert walls["spread_ratio"] >= 0.5 and walls["dataset_spread"]["std"] == pytest.approx(np.sqrt((26**2 - 1) / 12), rel=0.1)  # U{0..25}
    assert recon["vae"]["nll_per_world"] < recon["mean_image"]["nll_per_world"]
    assert measured["sensitivity"]["mean_changed_world_share"] > 0.5
    assert warnings == []


@pytest.mark.integration
def test_a_collapsed_generator_gets_the_collapse_warning(scatter_data, small_vae):
    config = replace(small_vae, beta=100.0, free_bits=0.0)
    vae = train_vae(scatter_data, config, progress=False)
    with registered():
        _, measured, warnings = measure(build_generator(vae, scatter_data), scatter_data, config)
    assert measured["latent"]["active_units"] < 2 and measured["latent"]["kl_total"] < 0.1
    collapsed = [line for line in warnings if line.startswith("collapsed:")]
    assert collapsed and all("--free-bits" in line and "\n" not in line for line in collapsed)


def test_a_repair_that_drops_the_walls_is_called_narrow(default_scatter, scatter_data, small_vae):
    """The issue's threshold repair: no cell of a sparse maze reaches p = 1/2, so G(z) has no walls."""
    vae = default_scatter[0]
    with registered():
        _, measured, warnings = measure(build_generator(vae, scatter_data, {"walls": "threshold"}), scatter_data, small_vae)
    assert measured["structure"]["wall_count"]["generator"] < 1 and measured["structure"]["wall_count"]["spread_ratio"] < 0.5
    assert any(line.startswith("narrow: wall_count") and "repair that keeps the decoded wall_count" in line for line in warnings)
    assert measured["structure"]["wall_count"]["ks_distance"] > 0.8  # mazes of under one wall against the dataset's many
    assert any(line.startswith("shifted: wall_count") and "repair's settings" in line for line in warnings)
    assert not any(line.startswith("collapsed:") for line in warnings)  # the VAE is fine; the repair is not


def test_latent_usage_counts_the_dimensions_the_encoder_moves(default_scatter, scatter_data):
    vae = default_scatter[0]
    with registered():
        generator = build_generator(vae, scatter_data)
        usage = latent_usage(generator, scatter_data.cells)
    mean, log_var = (np.asarray(a, np.float64) for a in vae.encode(scatter_data.cells))
    np.testing.assert_allclose(usage["activity_per_dim"], mean.var(axis=0), rtol=1e-4)
    np.testing.assert_allclose(usage["kl_per_dim"], 0.5 * (np.exp(log_var) + mean**2 - 1 - log_var).mean(axis=0), rtol=1e-4)
    assert usage["active_units"] == int((mean.var(axis=0) > 0.01).sum()) and usage["worlds"] == len(scatter_data)


def test_sensitivity_is_zero_for_a_decoder_that_ignores_z(default_scatter, scatter_data):
    vae = default_scatter[0]
    flat = jax.tree_util.tree_map(np.asarray, vae.params)
    flat["decoder_layers_0"]["kernel"] = np.zeros_like(flat["decoder_layers_0"]["kernel"])  # z no longer reaches the logits
    with registered():
        alive = sensitivity(build_generator(vae, scatter_data), np.asarray(jax.random.normal(jax.random.key(1), (20, 10))))
        dead = sensitivity(build_generator(replace(vae, params=flat), scatter_data), np.asarray(jax.random.normal(jax.random.key(1), (20, 10))))
    assert dead["mean_changed_world_share"] == 0 and dead["mean_probability_change"] == 0 and len(dead["changed_world_share"]) == 10
    assert alive["mean_changed_world_share"] > 0.5 and alive["mean_probability_change"] > 0 and alive["latents"] == 20


def healthy() -> tuple[dict, dict]:
    """Hand-made figures of a generator no threshold flags."""
    recon = {"vae": {"nll_per_world": 40.0}, "mean_image": {"nll_per_world": 50.0}}
    row = {
        "generator": 1.4,
        "dataset": 1.5,
        "ks_distance": 0.1,
        "spread_ratio": 0.9,
        "generator_spread": {"std": 0.9, "p5": 0.0, "p95": 3.0},
        "dataset_spread": {"std": 1.0, "p5": 0.0, "p95": 3.0},
    }
    measured = {
        "latent": {"active_units": 5, "kl_total": 4.0, "kl_per_dim": [0.8] * 5},
        "sensitivity": {"mean_changed_world_share": 0.7},
        "coverage_distinct_worlds": 950,
        "samples": 1000,
        "structure": {"walls": row},
    }
    return recon, measured


@pytest.mark.parametrize(
    "change, starts",
    [
        (lambda r, m: m["latent"].update(active_units=1), "collapsed: 1 of 5"),
        (lambda r, m: m["latent"].update(kl_total=0.0087), "collapsed:"),
        (lambda r, m: r["vae"].update(nll_per_world=49.9), "underfit: held-out reconstruction no better than the mean world"),
        (lambda r, m: m["sensitivity"].update(mean_changed_world_share=0.01), "inert:"),
        (lambda r, m: m.update(coverage_distinct_worlds=81), "inert:"),
        (lambda r, m: m["structure"]["walls"].update(spread_ratio=0.3), "narrow: walls spreads under G(z) 30% as wide"),
        (
            lambda r, m: m["structure"]["walls"].update(spread_ratio=0.0, generator_spread={"std": 0.0, "p5": 0.0, "p95": 0.0}),
            "narrow: walls is constant",
        ),
        (lambda r, m: m["structure"]["walls"].update(ks_distance=0.93, generator=0.48), "shifted: walls under G(z) is distributed unlike"),
    ],
)
def test_each_warning_fires_on_its_own_symptom(change, starts):
    recon, measured = healthy()
    assert diagnose(recon, measured, 10_000) == []
    change(recon, measured)
    warnings = diagnose(recon, measured, 10_000)
    assert len(warnings) == 1 and warnings[0].startswith(starts), warnings
    assert any(fix in warnings[0] for fix in ("--free-bits", "--repair", "--epochs"))  # each names its fix


def test_a_poor_held_out_fit_is_overfit_when_the_training_worlds_decode_well():
    recon, measured = healthy()
    recon["vae"]["nll_per_world"] = 60.0  # worse than the mean world's 50
    assert diagnose(recon, measured, 10_000, training_nll=20.0)[0].startswith("overfit:")
    assert diagnose(recon, measured, 10_000, training_nll=55.0)[0].startswith("underfit:")


def test_an_unused_z_before_the_training_worlds_beat_the_mean_world_is_underfit_not_collapsed():
    """ued_maze's tiny preset (3 epochs): 0 of 10 dimensions active, but not even the training mazes decode better than the
    mean maze; more free bits would not help, more epochs would."""
    recon, measured = healthy()
    recon["vae"]["nll_per_world"] = 663.5
    measured["latent"].update(active_units=0, kl_total=0.08)
    assert diagnose(recon, measured, 10_000)[0].startswith("collapsed: 0 of 5")  # without the training NLL: the old reading
    warnings = diagnose(recon, measured, 10_000, training_nll=591.7)
    assert len(warnings) == 1 and warnings[0].startswith("underfit: even the training worlds") and "--epochs" in warnings[0]


def test_distinct_decodes_are_judged_against_what_the_dataset_allows():
    recon, measured = healthy()
    measured["coverage_distinct_worlds"] = 30  # 30 of 1,000 draws, but the dataset holds only 100 worlds
    assert diagnose(recon, measured, 100) == [] and diagnose(recon, measured, 10_000)[0].startswith("inert:")
    measured["structure"]["walls"].update(spread_ratio=None)  # a descriptor constant in the dataset too: nothing to lose
    assert diagnose(recon, measured, 100) == []


def test_spread_gives_std_and_the_5_to_95_range():
    values = np.arange(101, dtype=float)
    assert spread(values) == {"std": pytest.approx(np.std(values)), "p5": 5.0, "p95": 95.0}
