"""How good is a generator? The figures ``worldagent generator report`` writes (paper §5.2.1).

- reconstruction of held-out worlds: cell accuracy, on-cell IoU and negative log-likelihood
  per world, each beside the same figure for the mean-image baseline (predict every world as
  the training set's mean cells);
- racing: self-mapping (the fraction of dataset tracks that encoder + G(z) maps back to
  themselves) and coverage (how many distinct dataset tracks G reaches from z ~ N(0, I));
- harvest: validity of decoded maps before repair (the thresholded decode passes
  ``validate()``, and has exactly K apples), after repair (always 1), and the diversity of walls
  among samples (distinct layouts, mean pairwise Hamming distance).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.errors import WorldagentError
from worldagent.worlds.dataset import WorldDataset
from worldagent.worlds.generator import Generator
from worldagent.worlds.repair import threshold_harvest

BATCH = 1000  # worlds per jitted call


def _batched(fn, array, *args):
    """``fn(args..., chunk)`` over chunks of ``array``, concatenated (bounded device memory)."""
    return np.concatenate([np.asarray(fn(*args, array[i : i + BATCH])) for i in range(0, len(array), BATCH)])


@jax.jit
def _reconstruct_logits(generator: Generator, cells):
    return generator.logits(generator.encode(cells))


@jax.jit
def _self_indices(generator: Generator, cells):
    return generator.track_indices(generator.encode(cells))


@jax.jit
def _sample_indices(generator: Generator, z):
    return generator.track_indices(z)


@jax.jit
def _sample_maps(generator: Generator, z):
    return generator(z), generator.logits(z)


def _cell_scores(logits: np.ndarray, cells: np.ndarray) -> dict:
    """Accuracy, on-cell IoU and NLL per world of Bernoulli ``logits`` against binary ``cells``."""
    predicted = logits > 0
    truth = cells.astype(bool)
    union = (predicted | truth).sum()
    nll = np.logaddexp(0.0, logits) - cells * logits  # softplus(l) - x·l, stable
    return {
        "accuracy": float((predicted == truth).mean()),
        "iou": float((predicted & truth).sum() / union) if union else 1.0,
        "nll_per_world": float(nll.sum(axis=1).mean()),
    }


def reconstruction(generator: Generator, dataset: WorldDataset, holdout: np.ndarray, train: np.ndarray) -> dict:
    """Held-out reconstruction figures of the VAE and of the mean-image baseline."""
    if len(holdout) == 0:
        raise WorldagentError("no held-out worlds to measure reconstruction on; train with --holdout > 0.")
    cells = dataset.cells[holdout].astype(np.float32)
    logits = _batched(_reconstruct_logits, cells, generator)
    mean = dataset.cells[train].mean(axis=0).clip(1e-4, 1 - 1e-4)
    baseline = np.broadcast_to(np.log(mean) - np.log1p(-mean), cells.shape)
    return {"vae": _cell_scores(logits, cells), "mean_image": _cell_scores(baseline, cells), "worlds": int(len(holdout))}


def racing_figures(generator: Generator, dataset: WorldDataset, samples: int, key: jax.Array) -> dict:
    """Self-mapping rate over the whole dataset and coverage of ``samples`` draws z ~ N(0, I)."""
    own = _batched(_self_indices, dataset.cells.astype(np.float32), generator)
    z = np.asarray(jax.random.normal(key, (samples, generator.latent_dim)))
    reached = _batched(_sample_indices, z, generator)
    counts = np.bincount(reached, minlength=len(dataset))
    return {
        "self_mapping_rate": float(np.mean(own == np.arange(len(dataset)))),
        "coverage_distinct_tracks": int((counts > 0).sum()),
        "coverage_fraction": float((counts > 0).mean()),
        "most_reached_share": float(counts.max() / samples),
        "samples": int(samples),
    }


def harvest_figures(generator: Generator, samples: int, key: jax.Array) -> dict:
    """Validity before / after repair and wall diversity of ``samples`` draws z ~ N(0, I)."""
    z = np.asarray(jax.random.normal(key, (samples, generator.latent_dim)))
    repaired_walls, repaired_apples, raw_valid, raw_exact = [], [], [], []
    for i in range(0, samples, BATCH):
        maps, logits = _sample_maps(generator, jnp.asarray(z[i : i + BATCH]))
        raw = threshold_harvest(np.asarray(logits).reshape(-1, *generator.cell_shape))
        raw_valid.append(_valid_each(raw))
        raw_exact.append(np.asarray(raw.apples).reshape(len(z[i : i + BATCH]), -1).sum(1) == generator.apples)
        repaired_walls.append(np.asarray(maps.walls))
        repaired_apples.append(np.asarray(maps.apples))
    walls = np.concatenate(repaired_walls)
    apples = np.concatenate(repaired_apples)
    from worldagent.envs.harvest.world import HarvestMap

    repaired_valid = _valid_each(HarvestMap(walls=walls, apples=apples)) & (apples.reshape(samples, -1).sum(1) == generator.apples)
    flat = walls.reshape(samples, -1)
    pairs = np.random.default_rng(0).integers(0, samples, size=(min(10_000, samples * 4), 2))
    return {
        "validity_before_repair": float(np.concatenate(raw_valid).mean()),
        "exact_apples_before_repair": float(np.concatenate(raw_exact).mean()),
        "validity_after_repair": float(repaired_valid.mean()),
        "distinct_wall_layouts": int(len(np.unique(flat, axis=0))),
        "mean_wall_hamming": float((flat[pairs[:, 0]] != flat[pairs[:, 1]]).sum(1).mean()),
        "apples_per_map": int(generator.apples),
        "samples": int(samples),
    }


def _valid_each(maps) -> np.ndarray:
    """bool[B]: whether each map of a batch passes ``HarvestMap.validate``."""
    from worldagent.envs.harvest.world import index_maps

    ok = []
    for i in range(len(np.asarray(maps.walls))):
        try:
            index_maps(maps, i).validate()
            ok.append(True)
        except WorldagentError:
            ok.append(False)
    return np.asarray(ok)
