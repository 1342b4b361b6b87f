"""The VAE learns, beats the mean image, saves, reloads and resumes."""

from __future__ import annotations

import json
from dataclasses import replace

import jax
import numpy as np
import pytest

from worldagent.errors import WorldagentError
from worldagent.worlds.quality import reconstruction
from worldagent.worlds.vae import TrainedVAE, split_holdout, train_vae


@pytest.mark.parametrize("which", ["racing", "harvest"])
def test_loss_falls_and_reconstructions_beat_the_mean_image(which, request, small_vae):
    vae = request.getfixturevalue(f"{which}_vae")
    data = request.getfixturevalue(f"{which}_data")
    generator = request.getfixturevalue(f"{which}_generator")
    nll = [h["nll"] for h in vae.history]  # the KL weight ramps up, so compare the reconstruction term
    assert nll[-1] < 0.6 * nll[0]
    train, held = split_holdout(len(data), small_vae.holdout, small_vae.seed)
    figures = reconstruction(generator, data, held, train)
    assert figures["vae"]["nll_per_world"] < figures["mean_image"]["nll_per_world"]


def test_checkpoint_reloads_and_encodes_identically(tmp_path, racing_vae, racing_data):
    loaded = TrainedVAE.load(racing_vae.save(tmp_path))
    cells = racing_data.cells[:5]
    np.testing.assert_array_equal(loaded.encode(cells)[0], racing_vae.encode(cells)[0])
    assert loaded.fingerprint == racing_data.fingerprint and loaded.history == racing_vae.history


def test_checkpoint_of_another_architecture_is_refused(tmp_path, racing_vae):
    racing_vae.save(tmp_path)
    meta = json.loads((tmp_path / "vae.json").read_text())
    meta["config"]["encoder"] = [128, 32]
    (tmp_path / "vae.json").write_text(json.dumps(meta))
    with pytest.raises(WorldagentError, match="do not fit the architecture"):
        TrainedVAE.load(tmp_path)
    with pytest.raises(WorldagentError, match="no readable VAE checkpoint"):
        TrainedVAE.load(tmp_path / "nowhere")


def test_killed_training_resumes_where_it_stopped(tmp_path, racing_data, small_vae):
    data = racing_data.subset(np.arange(96))
    short = replace(small_vae, epochs=2)
    first = train_vae(data, short, progress=False, checkpoint_dir=tmp_path)
    resumed = train_vae(data, replace(short, epochs=4), progress=False, checkpoint_dir=tmp_path)
    assert [h["epoch"] for h in resumed.history] == [1, 2, 3, 4]
    assert resumed.history[:2] == first.history
    straight = train_vae(data, replace(short, epochs=4), progress=False)
    np.testing.assert_allclose(resumed.history[-1]["train_loss"], straight.history[-1]["train_loss"], rtol=1e-4)


def test_a_finished_vae_copied_without_its_training_state_is_reused_and_an_unfinished_one_refused(tmp_path, racing_data, small_vae):
    data = racing_data.subset(np.arange(96))
    short = replace(small_vae, epochs=2)
    trained = train_vae(data, short, progress=False, checkpoint_dir=tmp_path / "run")
    copy = tmp_path / "copy"
    copy.mkdir()
    for name in ("vae.json", "vae.msgpack"):  # what a user copies of a trained generator
        (copy / name).write_bytes((tmp_path / "run" / name).read_bytes())
    reused = train_vae(data, short, progress=False, checkpoint_dir=copy)
    assert reused.history == trained.history
    jax.tree_util.tree_map(np.testing.assert_array_equal, reused.params, trained.params)
    with pytest.raises(WorldagentError, match="trained 2 of 4 epochs.*--epochs 2"):
        train_vae(data, replace(short, epochs=4), progress=False, checkpoint_dir=copy)


def test_resuming_on_other_data_is_refused(tmp_path, racing_data, small_vae):
    train_vae(racing_data.subset(np.arange(64)), replace(small_vae, epochs=1), progress=False, checkpoint_dir=tmp_path)
    with pytest.raises(WorldagentError, match="other data or settings"):
        train_vae(racing_data.subset(np.arange(64, 128)), replace(small_vae, epochs=2), progress=False, checkpoint_dir=tmp_path)


def test_bad_settings_are_refused(racing_data, small_vae):
    for bad in (replace(small_vae, holdout=1.0), replace(small_vae, epochs=0), replace(small_vae, latent_dim=0), replace(small_vae, free_bits=-1.0)):
        with pytest.raises(WorldagentError):
            train_vae(racing_data, bad, progress=False)
    with pytest.raises(WorldagentError, match="batch_size"):
        train_vae(racing_data.subset(np.arange(10)), small_vae, progress=False)


def test_free_bits_floor_each_dimensions_kl_in_the_loss_only():
    from worldagent.worlds.vae import negative_elbo

    logits, cells = np.zeros((4, 6), np.float32), np.ones((4, 6), np.float32)
    mean = np.array([[0.1, 2.0, 0.0]] * 4, np.float32)  # KL per dimension 0.005, 2 and 0 nats
    log_var = np.zeros((4, 3), np.float32)
    plain, (nll, kl) = negative_elbo(logits, cells, mean, log_var, 1.0)
    floored, (nll_floored, kl_floored) = negative_elbo(logits, cells, mean, log_var, 1.0, free_bits=0.5)
    assert float(kl) == float(kl_floored) == pytest.approx(2.005) and float(nll) == float(nll_floored) == pytest.approx(6 * np.log(2))
    assert float(plain) == pytest.approx(float(nll) + 2.005) and float(floored) == pytest.approx(float(nll) + 0.5 + 2.0 + 0.5)
    grad = jax.grad(lambda m: negative_elbo(logits, cells, m, log_var, 1.0, free_bits=0.5)[0])(mean)
    assert np.all(np.asarray(grad)[:, [0, 2]] == 0) and np.all(np.asarray(grad)[:, 1] > 0)  # under the floor, z is free


def test_old_checkpoints_load_with_the_training_they_had(tmp_path, racing_vae, racing_data, small_vae):
    """A vae.json written before free bits existed trained the plain ELBO: it loads with free_bits 0, and
    resuming it under the new default is refused with the setting named."""
    data = racing_data.subset(np.arange(64))
    old = replace(small_vae, epochs=1, free_bits=0.0)
    train_vae(data, old, progress=False, checkpoint_dir=tmp_path)
    meta = json.loads((tmp_path / "vae.json").read_text())
    del meta["config"]["free_bits"]
    (tmp_path / "vae.json").write_text(json.dumps(meta))
    assert TrainedVAE.load(tmp_path).config == old
    assert len(train_vae(data, replace(old, epochs=2), progress=False, checkpoint_dir=tmp_path).history) == 2
    with pytest.raises(WorldagentError, match=r"free_bits 0\.0, not 0\.5"):
        train_vae(data, replace(old, epochs=3, free_bits=0.5), progress=False, checkpoint_dir=tmp_path)


def _history(losses: list[float]) -> list[dict]:
    return [{"epoch": i + 1, "holdout_loss": loss} for i, loss in enumerate(losses)]


def test_the_kept_epoch_is_the_lowest_held_out_loss_after_warm_up():
    from worldagent.worlds.vae import kept_epoch

    assert kept_epoch(_history([90.0, 50.0, 70.0, 60.0, 60.0, 65.0]), warmup_epochs=2) == 4  # epoch 2 is in warm-up; ties: the earliest
    assert kept_epoch(_history([90.0, 80.0, float("nan"), 85.0]), warmup_epochs=1) == 2  # a NaN held-out loss is never kept
    assert kept_epoch(_history([90.0, 50.0]), warmup_epochs=5) == 2  # all within warm-up: the last
    assert kept_epoch(_history([float("nan")] * 3), warmup_epochs=0) == 3  # no held-out split: the last
    assert kept_epoch([], warmup_epochs=0) == 0
    # the objective training minimises (free bits included) decides, where the history has it
    rows = [{**row, "holdout_objective": objective} for row, objective in zip(_history([55.0, 54.7, 55.3]), [60.0, 58.0, 56.0])]
    assert kept_epoch(rows, warmup_epochs=0) == 3


def test_training_stops_patience_epochs_after_the_best():
    from worldagent.worlds.vae import VAEConfig, stopped_early

    config = VAEConfig(warmup_epochs=1, patience=2)
    assert not stopped_early(_history([90.0, 80.0, 85.0]), config)  # one epoch since the best
    assert stopped_early(_history([90.0, 80.0, 85.0, 81.0]), config)
    assert not stopped_early(_history([90.0, 80.0, 85.0, 81.0]), replace(config, patience=0))  # 0: every epoch
    assert not stopped_early(_history([50.0, 80.0, 85.0]), replace(config, warmup_epochs=3))  # within warm-up: never


def _unlike_held_out_worlds(holdout: float, seed: int):
    """64 worlds whose held-out ones (``split_holdout``) fill the 24 cells every training world leaves empty: the
    longer a VAE trains, the surer it is that those cells are empty, and the worse its held-out loss."""
    from worldagent.worlds.dataset import WorldDataset

    cells = np.zeros((64, 48), np.uint8)
    cells[:, :24] = np.random.default_rng(0).random((64, 24)) < 0.3
    cells[split_holdout(64, holdout, seed)[1], 24:] = 1
    return WorldDataset("racing", np.arange(64), None, cells, (48,))


def _same(a, b) -> bool:
    return jax.tree_util.tree_all(jax.tree_util.tree_map(lambda x, y: np.allclose(x, y, atol=1e-6), a, b))


DIVERGING = {"holdout": 0.25, "warmup_epochs": 1, "patience": 0, "encoder": (16, 8), "decoder": (8, 16)}


@pytest.mark.integration
def test_training_keeps_the_best_held_out_epochs_weights(tmp_path, small_vae):
    """4 epochs return (and save) the same weights as 3: the kept epoch's, not the last's."""
    config = replace(small_vae, epochs=4, **DIVERGING)
    data = _unlike_held_out_worlds(config.holdout, config.seed)
    straight = train_vae(data, config, progress=False)
    first = train_vae(data, replace(config, epochs=3), progress=False, checkpoint_dir=tmp_path)
    kept = first.kept_epoch
    assert kept == 2 and straight.kept_epoch == kept and first.kept == first.history[kept - 1]
    assert _same(straight.params, first.params) and _same(TrainedVAE.load(tmp_path).params, first.params)


@pytest.mark.slow
def test_a_resumed_run_goes_on_from_the_last_epoch_not_the_kept_one(tmp_path, small_vae):
    config = replace(small_vae, epochs=7, **DIVERGING)
    data = _unlike_held_out_worlds(config.holdout, config.seed)
    first = train_vae(data, replace(config, epochs=6), progress=False, checkpoint_dir=tmp_path)
    kept = first.kept_epoch
    assert kept < 6
    resumed = train_vae(data, config, progress=False, checkpoint_dir=tmp_path)
    straight = train_vae(data, config, progress=False)
    assert resumed.history[-1]["train_loss"] == pytest.approx(straight.history[-1]["train_loss"], rel=1e-4)
    stopped = train_vae(data, replace(config, epochs=50, patience=7 - kept), progress=False, checkpoint_dir=tmp_path)
    assert len(stopped.history) == 7 and TrainedVAE.load(tmp_path).kept_epoch == kept  # patience spent: no further epoch
