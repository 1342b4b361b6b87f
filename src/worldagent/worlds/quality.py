"""How good is a generator? The figures ``worldagent generator report`` writes (paper §5.2.1).

- ``reconstruction``: on held-out worlds, cell accuracy, on-cell IoU and negative
  log-likelihood per world, each beside the same figure for the mean-image baseline (predict
  every world as the training set's mean cells);
- ``figures``: self-mapping (the fraction of dataset worlds that G(encode(x)) maps back to
  themselves), coverage (how many distinct worlds G reaches from z ~ N(0, I), and which share of
  the dataset's worlds it reproduces), validity of
  G(z) after repair and, where the spec has a ``raw_decode``, before it, and the diversity of
  the samples' cells (distinct layouts, mean pairwise Hamming distance);
- ``structure``: each of the environment's descriptors (e.g. harvest's share of maps whose walls
  cut the tagger off from another agent) over G(z) samples against the dataset.

Worlds are compared by their cells (``EnvSpec.cells``), so nothing here depends on the
environment: racing's nearest-track repair and harvest's apple-count repair get the same figures.
"""

from __future__ import annotations

from collections import Counter

import jax
import numpy as np

from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.worlds.dataset import WorldDataset
from worldagent.worlds.generator import Generator

BATCH = 1000  # worlds per jitted call
HAMMING_PAIRS = 10_000  # sample pairs for the mean Hamming distance
STRUCTURE_WORLDS = 2000  # worlds of each side whose descriptors are compared (computed on the host, one by one)


def _batched(fn, array, *args):
    """``fn(args..., chunk)`` over chunks of ``array``, concatenated (bounded device memory)."""
    return np.concatenate([np.asarray(fn(*args, array[i : i + BATCH])) for i in range(0, len(array), BATCH)])


@jax.jit
def _reconstruct_logits(generator: Generator, cells):
    return generator.logits(generator.encode(cells))


@jax.jit
def _reconstruct_worlds(generator: Generator, cells):
    return generator(generator.encode(cells))


@jax.jit
def _sample(generator: Generator, z):
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
    """Held-out reconstruction figures of the VAE and of the mean-image baseline.

    Args:
        generator: G (its encoder and decoder are used, not its repair).
        dataset: the worlds; ``cells`` uint8[N, D].
        holdout: int[H] indices of the held-out worlds.
        train: int[T] indices of the training worlds (for the mean image).
    """
    if len(holdout) == 0:
        raise WorldagentError("no held-out worlds to measure reconstruction on; train with --holdout > 0.")
    cells = dataset.cells[holdout].astype(np.float32)
    logits = _batched(_reconstruct_logits, cells, generator)
    mean = dataset.cells[train].mean(axis=0).clip(1e-4, 1 - 1e-4)
    baseline = np.broadcast_to(np.log(mean) - np.log1p(-mean), cells.shape)
    return {"vae": _cell_scores(logits, cells), "mean_image": _cell_scores(baseline, cells), "worlds": int(len(holdout))}


def _each(worlds, count: int):
    """The ``count`` unbatched worlds of a batch, as numpy (copied to the host once)."""
    worlds = jax.tree_util.tree_map(np.asarray, worlds)
    return (jax.tree_util.tree_map(lambda leaf, i=i: leaf[i], worlds) for i in range(count))


def _valid(world) -> bool:
    try:
        world.validate()
    except WorldagentError:
        return False
    return True


def _valid_each(worlds, count: int) -> np.ndarray:
    """bool[B]: whether each world of a batch passes ``validate()`` (host-side, one by one)."""
    if _valid(worlds):  # validate() takes a batch too: when all pass, skip the per-world loop
        return np.ones(count, bool)
    return np.fromiter((_valid(world) for world in _each(worlds, count)), bool, count)


def _concat(batches: list):
    """One batched world from chunks of batched worlds."""
    return jax.tree_util.tree_map(lambda *leaves: np.concatenate([np.asarray(leaf) for leaf in leaves]), *batches)


def _self_mapping_rate(generator: Generator, dataset: WorldDataset, spec) -> float:
    """Fraction of dataset worlds x with cells(G(encode(x))) == cells(x)."""
    cells = dataset.cells.astype(np.float32)
    rebuilt = [spec.cells(_reconstruct_worlds(generator, cells[i : i + BATCH])) for i in range(0, len(cells), BATCH)]
    return float(np.mean(np.all(np.concatenate(rebuilt) == dataset.cells, axis=1)))


def _diversity(cells: np.ndarray, dataset_cells: np.ndarray) -> dict:
    """Coverage and diversity figures of the samples' cells uint8[S, D] against the dataset's uint8[N, D]."""
    samples = len(cells)
    seen = Counter(row.tobytes() for row in cells)  # hashing rows: np.unique(axis=0) sorts them, far slower
    counts = np.fromiter(seen.values(), np.int64, len(seen))
    reached = seen.keys() & {row.tobytes() for row in dataset_cells}
    pairs = np.random.default_rng(0).integers(0, samples, size=(min(HAMMING_PAIRS, samples * 4), 2))
    return {
        "coverage_distinct_worlds": int(len(counts)),
        "coverage_fraction": float(len(reached) / len(dataset_cells)),
        "most_reached_share": float(counts.max() / samples),
        "distinct_layouts": int(len(counts)),
        "mean_cell_hamming": float((cells[pairs[:, 0]] != cells[pairs[:, 1]]).sum(1).mean()),
    }


def structure(spec, generated, count: int, dataset: WorldDataset) -> dict:
    """Each of the spec's descriptors (``Metrics.descriptors``) averaged over G(z) samples and over the dataset.

    A generator can match cells on average and still break what matters about a world (a wall
    with a gap encloses nothing); the descriptors measure such structure. Up to
    ``STRUCTURE_WORLDS`` worlds of each side.

    Returns:
        ``{name: {"generator": mean, "dataset": mean, "relative_difference": (g - d) / d or None}}``.
    """
    count = min(count, STRUCTURE_WORLDS)
    reference = min(len(dataset), STRUCTURE_WORLDS)
    out = {}
    for name, describe in spec.metrics.descriptors.items():
        ours = float(np.mean([describe(world) for world in _each(generated, count)]))
        theirs = float(np.mean([describe(world) for world in _each(dataset.worlds, reference)]))
        out[name] = {"generator": ours, "dataset": theirs, "relative_difference": (ours - theirs) / theirs if theirs else None}
    return out


def figures(generator: Generator, dataset: WorldDataset, samples: int, key: jax.Array) -> dict:
    """Self-mapping over the dataset; coverage, validity and diversity of ``samples`` draws z ~ N(0, I).

    Args:
        generator: G, built on ``dataset``.
        dataset: its training dataset (N worlds).
        samples: S, the number of latents drawn from the prior.
        key: PRNG key of the draws.

    Returns:
        ``self_mapping_rate``, ``coverage_distinct_worlds`` (distinct sampled worlds, by cells),
        ``coverage_fraction`` (the share of dataset worlds some sample equals), ``most_reached_share`` (the commonest sample's
        share), ``validity_after_repair``, ``validity_before_repair`` (only when the spec has a
        ``raw_decode``), ``distinct_layouts``, ``mean_cell_hamming`` (between random sample
        pairs), ``structure`` (``structure``: the spec's descriptors, G(z) against the dataset)
        and ``samples``.
    """
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 1:
        raise WorldagentError(f"samples={samples!r}; draw at least 1 latent.")
    spec = registry.get(generator.env)
    z = np.asarray(jax.random.normal(key, (samples, generator.latent_dim)))
    worlds, valid_after, valid_before = [], [], []
    for start in range(0, samples, BATCH):
        chunk, logits = _sample(generator, z[start : start + BATCH])
        chunk, count = jax.tree_util.tree_map(np.asarray, chunk), len(z[start : start + BATCH])
        worlds.append(chunk)
        valid_after.append(_valid_each(chunk, count))
        if spec.raw_decode is not None:
            valid_before.append(_valid_each(spec.raw_decode(np.asarray(logits)), count))
    worlds = _concat(worlds)
    cells = np.asarray(spec.cells(worlds), np.uint8)
    result = {"self_mapping_rate": _self_mapping_rate(generator, dataset, spec), **_diversity(cells, dataset.cells)}
    result["structure"] = structure(spec, worlds, samples, dataset)
    result["validity_after_repair"] = float(np.concatenate(valid_after).mean())
    if valid_before:
        result["validity_before_repair"] = float(np.concatenate(valid_before).mean())
    return {**result, "samples": int(samples)}
