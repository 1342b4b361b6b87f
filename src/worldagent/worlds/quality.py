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
  cut the tagger off from another agent) over G(z) samples against the dataset: mean, spread
  (standard deviation, 5-95% range) and their ratio;
- ``latent``: KL per latent dimension and active units (Burda et al. 2016), over the dataset's
  encodings: does z carry anything about the world?
- ``sensitivity``: how much G(z) changes when z moves one prior standard deviation along each axis;
- ``coverage``: G(z) against fresh worlds of the env's own generator at unused seeds, not the
  dataset (``worlds.coverage``): precision, recall, density and coverage, descriptor quantiles and,
  where the env declares them, its generator parameters' spread;
- ``diagnose``: one-line warnings, each naming its fix, when a generator is collapsed (z carries
  nothing), inert (moving z changes no world), narrow (a descriptor spreads far less than in the
  dataset), shifted or uncovered (it reaches under half of what the env's generator makes) — such
  a generator gives search nothing to find, whatever its loss says.
- ``gate``: the verdict on those warnings: passed (none), rejected (any), or waived (rejected, but
  used for a recorded reason);
- ``assess``: all of the above for a trained generator, as ``quality.json`` holds it.

Worlds are compared by their cells (``EnvSpec.cells``), so nothing here depends on the
environment: racing's nearest-track repair and harvest's apple-count repair get the same figures.
"""

from __future__ import annotations

from collections import Counter

import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats

from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.progress import progress_bar
from worldagent.worlds.coverage import COVERAGE_WORLDS, NEIGHBOURS, coverage
from worldagent.worlds.dataset import WorldDataset
from worldagent.worlds.generator import Generator
from worldagent.worlds.vae import VAE, split_holdout

BATCH = 1000  # worlds per jitted call
HAMMING_PAIRS = 10_000  # sample pairs for the mean Hamming distance
STRUCTURE_WORLDS = 2000  # worlds of each side whose descriptors are compared (computed on the host, one by one)
USAGE_WORLDS = 10_000  # dataset worlds whose encodings measure the latent's use
SELF_MAPPING_WORLDS = 1000  # dataset worlds rebuilt by G(encode(x)): a rate to +-3 points; harvest's open repair takes 20-55 ms a world
SENSITIVITY_LATENTS = 100  # prior draws moved ±1 along each axis (2·L·100 decodes)
ACTIVE_UNIT_VARIANCE = 0.01  # Burda et al. 2016: a dimension is active when Cov_x(E_q[z_d|x]) exceeds it


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


@jax.jit
def _posterior(generator: Generator, cells):
    mean, log_var = generator.model.apply({"params": generator.params}, jnp.asarray(cells, jnp.float32), method=VAE.encode)
    return jnp.concatenate([mean, log_var], axis=1)


def latent_usage(generator: Generator, cells: np.ndarray) -> dict:
    """How much of z the encoder uses: KL per dimension and active units.

    Args:
        generator: G (its encoder is used).
        cells: uint8[N, D] the worlds to encode (N >= 2).

    Returns:
        ``kl_per_dim`` (L floats, nats: the mean over the worlds of KL(q(z_d|x) || N(0, 1))),
        ``kl_total`` (their sum), ``activity_per_dim`` (L floats: the variance over the worlds of
        the posterior mean E_q[z_d|x]), ``active_units`` (dimensions whose activity exceeds
        ``ACTIVE_UNIT_VARIANCE``, Burda et al. 2016) and ``worlds`` (N).
    """
    posterior = _batched(_posterior, np.asarray(cells, np.float32), generator)
    mean, log_var = np.split(posterior.astype(np.float64), 2, axis=1)
    kl = 0.5 * (np.exp(log_var) + mean**2 - 1.0 - log_var).mean(axis=0)
    activity = mean.var(axis=0)
    return {
        "kl_per_dim": kl.tolist(),
        "kl_total": float(kl.sum()),
        "activity_per_dim": activity.tolist(),
        "active_units": int((activity > ACTIVE_UNIT_VARIANCE).sum()),
        "worlds": int(len(cells)),
    }


def _decode_cells(generator: Generator, spec, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cells uint8[S, D] of G(z), decoded probabilities f32[S, D]) for latents f32[S, L]."""
    cells, probabilities = [], []
    for start in range(0, len(z), BATCH):
        worlds, logits = _sample(generator, z[start : start + BATCH])
        cells.append(np.asarray(spec.cells(jax.tree_util.tree_map(np.asarray, worlds)), np.uint8))
        probabilities.append(np.asarray(jax.nn.sigmoid(logits)))
    return np.concatenate(cells), np.concatenate(probabilities)


def sensitivity(generator: Generator, z: np.ndarray) -> dict:
    """How much G(z) changes when each latent coordinate moves by ±1 (one prior standard deviation).

    Args:
        generator: G.
        z: f32[S, L] latents (prior draws) to move from.

    Returns:
        Per dimension (L floats each): ``changed_world_share`` (the share of the 2·S moves whose
        repaired world differs), ``changed_cell_share`` (mean share of its cells that differ) and
        ``probability_change`` (mean |Δp| over the decoded cell probabilities, before repair);
        ``mean_changed_world_share``, ``mean_changed_cell_share`` and ``mean_probability_change``
        (their means over dimensions) and ``latents`` (S).
    """
    spec = registry.get(generator.env)
    z = np.asarray(z, np.float32)
    samples, dims = z.shape
    steps = np.concatenate([np.eye(dims, dtype=np.float32), -np.eye(dims, dtype=np.float32)])  # f32[2L, L]
    moved = (z[None, :, :] + steps[:, None, :]).reshape(-1, dims)  # f32[2L·S, L], grouped by move
    cells, probability = _decode_cells(generator, spec, np.concatenate([z, moved]))
    base_cells, base_p = cells[:samples], probability[:samples]
    moved_cells = cells[samples:].reshape(2, dims, samples, -1)
    moved_p = probability[samples:].reshape(2, dims, samples, -1)
    differs = moved_cells != base_cells
    world = differs.any(axis=-1).mean(axis=(0, 2))
    cell = differs.mean(axis=(0, 2, 3))
    delta = np.abs(moved_p - base_p).mean(axis=(0, 2, 3))
    return {
        "changed_world_share": world.tolist(),
        "changed_cell_share": cell.tolist(),
        "probability_change": delta.tolist(),
        "mean_changed_world_share": float(world.mean()),
        "mean_changed_cell_share": float(cell.mean()),
        "mean_probability_change": float(delta.mean()),
        "latents": int(samples),
    }


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
    """Fraction of the first ``SELF_MAPPING_WORLDS`` dataset worlds x with cells(G(encode(x))) == cells(x)."""
    cells = dataset.cells[:SELF_MAPPING_WORLDS]
    rebuilt = [spec.cells(_reconstruct_worlds(generator, cells[i : i + BATCH].astype(np.float32))) for i in range(0, len(cells), BATCH)]
    return float(np.mean(np.all(np.concatenate(rebuilt) == cells, axis=1)))


def _diversity(cells: np.ndarray, dataset_cells: np.ndarray) -> dict:
    """Coverage and diversity figures of the samples' cells uint8[S, D] against the dataset's uint8[N, D]."""
    samples = len(cells)
    seen = Counter(row.tobytes() for row in cells)  # hashing rows: np.unique(axis=0) sorts them, far slower
    counts = np.fromiter(seen.values(), np.int64, len(seen))
    known = {row.tobytes() for row in dataset_cells}
    reached = seen.keys() & known
    pairs = np.random.default_rng(0).integers(0, samples, size=(min(HAMMING_PAIRS, samples * 4), 2))
    return {
        "coverage_distinct_worlds": int(len(counts)),
        "distinct_share": float(len(counts) / samples),
        "novel_share": float(sum(count for row, count in seen.items() if row not in known) / samples),
        "coverage_fraction": float(len(reached) / len(dataset_cells)),
        "most_reached_share": float(counts.max() / samples),
        "distinct_layouts": int(len(counts)),
        "mean_cell_hamming": float((cells[pairs[:, 0]] != cells[pairs[:, 1]]).sum(1).mean()),
    }


def spread(values: np.ndarray) -> dict:
    """``std`` and the 5-95% range ``p5``, ``p95`` of f[N] values."""
    low, high = np.percentile(values, [5, 95])
    return {"std": float(np.std(values)), "p5": float(low), "p95": float(high)}


def structure(spec, generated, count: int, dataset: WorldDataset) -> dict:
    """Each of the spec's descriptors (``Metrics.descriptors``) over G(z) samples against the dataset: mean and spread.

    A generator can match cells on average and still break what matters about a world (a wall
    with a gap encloses nothing), or match the mean and lose the spread (every maze with the
    mean wall count); the descriptors measure such structure. Up to ``STRUCTURE_WORLDS`` worlds
    of each side.

    Returns:
        ``{name: {"generator": mean, "dataset": mean, "relative_difference": (g - d) / d or None,
        "generator_spread": spread, "dataset_spread": spread, "spread_ratio": g std / d std or None,
        "ks_distance": the largest gap between the two empirical CDFs}}`` (``spread``: std, p5, p95; the ratio is None
        when the dataset's std is 0).
    """
    count = min(count, STRUCTURE_WORLDS)
    reference = min(len(dataset), STRUCTURE_WORLDS)
    out = {}
    for name, describe in spec.metrics.descriptors.items():
        ours = np.array([describe(world) for world in _each(generated, count)], np.float64)
        theirs = np.array([describe(world) for world in _each(dataset.worlds, reference)], np.float64)
        mean, reference_mean = float(ours.mean()), float(theirs.mean())
        ours_spread, theirs_spread = spread(ours), spread(theirs)
        out[name] = {
            "generator": mean,
            "dataset": reference_mean,
            "relative_difference": (mean - reference_mean) / reference_mean if reference_mean else None,
            "generator_spread": ours_spread,
            "dataset_spread": theirs_spread,
            "spread_ratio": ours_spread["std"] / theirs_spread["std"] if theirs_spread["std"] > 0 else None,
            "ks_distance": float(stats.ks_2samp(ours, theirs).statistic),
        }
    return out


def figures(generator: Generator, dataset: WorldDataset, samples: int, key: jax.Array, progress: bool = False) -> dict:
    """Self-mapping over the dataset; coverage, validity and diversity of ``samples`` draws z ~ N(0, I).

    Args:
        generator: G, built on ``dataset``.
        dataset: its training dataset (N worlds).
        samples: S, the number of latents drawn from the prior.
        key: PRNG key of the draws.
        progress: draw a bar over the decodes (harvest's open repair takes 20-55 ms a world).

    Returns:
        ``self_mapping_rate`` (over the first ``SELF_MAPPING_WORLDS``), ``coverage_distinct_worlds`` (distinct sampled worlds, by cells),
        ``coverage_fraction`` (the share of dataset worlds some sample equals), ``most_reached_share`` (the commonest sample's
        share), ``validity_after_repair``, ``validity_before_repair`` (only when the spec has a
        ``raw_decode``), ``distinct_layouts``, ``mean_cell_hamming`` (between random sample
        pairs), ``distinct_share`` (distinct worlds / S), ``novel_share`` (the share of samples
        equal to no dataset world), ``structure`` (``structure``: the spec's descriptors, G(z)
        against the dataset), ``coverage`` (``worlds.coverage.coverage``: the first
        min(S, N, ``COVERAGE_WORLDS``) draws against as many fresh worlds of the env's generator at
        unused seeds; absent when that is ``NEIGHBOURS`` or fewer), ``latent`` (``latent_usage``
        over up to ``USAGE_WORLDS`` dataset worlds), ``sensitivity`` (``sensitivity`` from the first
        ``SENSITIVITY_LATENTS`` draws) and ``samples``.
    """
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 1:
        raise WorldagentError(f"samples={samples!r}; draw at least 1 latent.")
    spec = registry.get(generator.env)
    z = np.asarray(jax.random.normal(key, (samples, generator.latent_dim)))
    worlds, valid_after, valid_before = [], [], []
    with progress_bar(f"decoding {samples:,} draws of G(z)", samples, progress) as advance:
        for start in range(0, samples, BATCH):
            chunk, logits = _sample(generator, z[start : start + BATCH])
            chunk, count = jax.tree_util.tree_map(np.asarray, chunk), len(z[start : start + BATCH])
            worlds.append(chunk)
            valid_after.append(_valid_each(chunk, count))
            if spec.raw_decode is not None:
                valid_before.append(_valid_each(spec.raw_decode(np.asarray(logits)), count))
            advance(count)
    worlds = _concat(worlds)
    cells = np.asarray(spec.cells(worlds), np.uint8)
    result = {"self_mapping_rate": _self_mapping_rate(generator, dataset, spec), **_diversity(cells, dataset.cells)}
    result["structure"] = structure(spec, worlds, samples, dataset)
    result["latent"] = latent_usage(generator, dataset.cells[:USAGE_WORLDS])
    result["sensitivity"] = sensitivity(generator, z[:SENSITIVITY_LATENTS])
    fresh = min(samples, len(dataset), COVERAGE_WORLDS)  # a tiny dataset's run compares as many worlds as it has
    if fresh > NEIGHBOURS:
        result["coverage"] = coverage(spec, worlds, fresh, dataset)
    result["validity_after_repair"] = float(np.concatenate(valid_after).mean())
    if valid_before:
        result["validity_before_repair"] = float(np.concatenate(valid_before).mean())
    return {**result, "samples": int(samples)}


# -- warnings ---------------------------------------------------------------------------------
# Each threshold flags a generator that search cannot use, not one that is merely imperfect.
OVERFIT_RATIO = 0.5  # training worlds decoded with under half the held-out NLL: the VAE memorised them
MIN_ACTIVE_UNITS = 2  # one active dimension is a dial, not a space: search has one direction to move in
MIN_KL_NATS = float(np.log(2))  # under one bit of KL in all of z, the code cannot even split the dataset in two
MIN_NLL_GAIN = 0.01  # held-out NLL within 1% of the mean world's: the decoder ignores z
MIN_CHANGED_WORLD_SHARE = 0.05  # a one-standard-deviation move changes fewer than 1 world in 20
MIN_DISTINCT_SHARE = 0.1  # fewer distinct decodes than 1 in 10 of min(samples, dataset worlds)
MIN_SPREAD_RATIO = 0.5  # a descriptor's std under G(z) below half the dataset's: its tails are out of search's reach
# A descriptor whose distribution under G(z) is shifted: at some value, the shares of decoded and dataset worlds
# below it differ by more than half (two-sample Kolmogorov-Smirnov distance). A spread can match while the mean is
# elsewhere (mazes of 0.5 walls against the dataset's 23); this flags gross shifts only.
MAX_KS_DISTANCE = 0.5
RETRAIN = "retrain with a larger --free-bits (e.g. 1.0), a smaller --beta or more worlds"
# G(z) reaches under half of the env's own generator: its coverage (Naeem et al. 2020) or recall (Kynkäänniemi et
# al. 2019) against fresh worlds below half of what a second sample of fresh worlds scores (the floor, at 1,000
# worlds: coverage 0.96-0.97, recall 0.94-0.98). The quick-run generators (docs/generator.md) score coverage
# 0.95 (racing) and 0.54-0.63 (harvest: 0.55-0.65 of the floor), recall 0.93-0.97 and 0.55-0.62 (0.58-0.66 of it):
# all pass; scatter mazes limited to their quarter with the fewest walls do not. Half, as MIN_SPREAD_RATIO: a flag
# for a generator search cannot use, not for one that is merely imperfect (harvest's apples, docs/generator.md).
MIN_COVERED_SHARE = 0.5


def _collapse(reconstruction: dict, latent: dict, training_nll: float | None) -> list[str]:
    units, kl = latent["active_units"], latent["kl_total"]
    dims = len(latent["kl_per_dim"])
    vae, mean = reconstruction["vae"]["nll_per_world"], reconstruction["mean_image"]["nll_per_world"]
    if training_nll is not None and training_nll > (1 - MIN_NLL_GAIN) * mean:
        # nothing learnt yet, not even the mean world: an unused z says nothing of collapse (ued_maze's tiny preset,
        # 3 epochs: 0 of 10 dimensions active at a training NLL of 592 against the mean maze's 58), and free bits cannot help
        return [
            f"underfit: even the training worlds decode no better than the mean world (training NLL {training_nll:.1f}, held-out {vae:.1f}, "
            f"mean world {mean:.1f} nats per world; {units} of {dims} latent dimensions active) — train longer (more --epochs)."
        ]
    out = []
    if units < MIN_ACTIVE_UNITS or kl < MIN_KL_NATS:
        out.append(f"collapsed: {units} of {dims} latent dimensions active, KL {kl:.3g} nats in all; G(z) barely depends on z — {RETRAIN}.")
    if vae <= (1 - MIN_NLL_GAIN) * mean:
        return out
    said = f"held-out reconstruction no better than the mean world (NLL {vae:.1f} vs {mean:.1f} nats per world)"
    if out:
        out.append(f"collapsed: {said}: z tells the decoder nothing it can use — {RETRAIN}, or train longer.")
    elif training_nll is not None and training_nll < OVERFIT_RATIO * vae:  # z in use and training worlds decoded well: memorised
        out.append(
            f"overfit: {said}, training NLL {training_nll:.1f}: the VAE memorised its training worlds — train fewer --epochs or on more worlds."
        )
    else:
        out.append(f"underfit: {said} though {units} of {dims} latent dimensions are in use — train longer (more --epochs).")
    return out


def _inert(figures: dict, worlds: int) -> list[str]:
    moves = figures["sensitivity"]["mean_changed_world_share"]
    distinct, samples = figures["coverage_distinct_worlds"], figures["samples"]
    if moves < MIN_CHANGED_WORLD_SHARE or distinct < MIN_DISTINCT_SHARE * min(samples, worlds):
        return [
            f"inert: a one-standard-deviation move along z changes {moves:.0%} of worlds and {samples:,} draws give {distinct:,} distinct worlds; "
            "the repair discards what the decoder varies — try another --repair, or retrain with a larger --free-bits."
        ]
    return []


def _narrow(structure: dict) -> list[str]:
    out = []
    for name, row in structure.items():
        ratio, ours, theirs = row.get("spread_ratio"), row.get("generator_spread"), row.get("dataset_spread")
        if ratio is None or ratio >= MIN_SPREAD_RATIO:
            continue
        shape = "is constant under G(z)" if ours["std"] == 0 else f"spreads under G(z) {ratio:.0%} as wide as in the dataset"
        out.append(
            f"narrow: {name} {shape} (std {ours['std']:.3g} vs {theirs['std']:.3g}, 5-95% "
            f"{ours['p5']:.3g}-{ours['p95']:.3g} vs {theirs['p5']:.3g}-{theirs['p95']:.3g}): search cannot reach its tails — "
            f"use a repair that keeps the decoded {name}, or retrain with a larger --free-bits."
        )
    return out


def _shifted(structure: dict) -> list[str]:
    out = []
    for name, row in structure.items():
        distance = row.get("ks_distance")
        if distance is None or distance <= MAX_KS_DISTANCE:
            continue
        ours, theirs = row["generator_spread"], row["dataset_spread"]
        out.append(
            f"shifted: {name} under G(z) is distributed unlike the dataset's (mean {row['generator']:.3g} vs {row['dataset']:.3g}, "
            f"5-95% {ours['p5']:.3g}-{ours['p95']:.3g} vs {theirs['p5']:.3g}-{theirs['p95']:.3g}, KS distance {distance:.2f}): "
            "searches explore other worlds than the env makes — check the repair's settings, or retrain (more --epochs, a larger --free-bits)."
        )
    return out


def _uncovered(coverage: dict | None) -> list[str]:
    if not coverage:
        return []
    floor = coverage.get("floor") or {"coverage": 1.0, "recall": 1.0}
    low = [name for name in ("coverage", "recall") if coverage[name] < MIN_COVERED_SHARE * floor[name]]
    if not low:
        return []
    shown = ", ".join(f"{name} {coverage[name]:.2f} (fresh against fresh {floor[name]:.2f})" for name in ("coverage", "recall"))
    return [
        f"uncovered: G(z) reaches under half of what the env's own generator makes ({shown}; {coverage['worlds']:,} decodes against "
        f"{coverage['worlds']:,} fresh worlds at unused seeds): search cannot reach most of the env's worlds — try another --repair "
        "(`worldagent envs` lists them, e.g. --repair open), or retrain (more --epochs, a larger --free-bits)."
    ]


def diagnose(reconstruction: dict, figures: dict, worlds: int, training_nll: float | None = None) -> list[str]:
    """One-line warnings, each naming its fix, for a generator search cannot use (empty: none).

    Collapsed: fewer than ``MIN_ACTIVE_UNITS`` active dimensions or under ``MIN_KL_NATS`` of KL
    (and then also a held-out reconstruction within ``MIN_NLL_GAIN`` of the mean world's). Overfit:
    that poor a held-out reconstruction while z is in use and the training worlds decode well
    (training NLL under ``OVERFIT_RATIO`` of the held-out); underfit: neither decodes well yet, or
    the training worlds decode no better than the mean world (then no collapse is claimed: nothing
    is learnt yet, and training longer is the fix, not free bits). Inert: a ±1 move
    along z changes under ``MIN_CHANGED_WORLD_SHARE`` of worlds, or the draws hold under
    ``MIN_DISTINCT_SHARE`` distinct worlds. Narrow: a descriptor whose std under G(z) is below
    ``MIN_SPREAD_RATIO`` of the dataset's. Shifted: a descriptor whose distribution under G(z) is more than
    ``MAX_KS_DISTANCE`` (Kolmogorov-Smirnov) from the dataset's. Uncovered: G(z)'s coverage or recall against
    fresh worlds of the env's generator (``figures``' ``coverage``) below ``MIN_COVERED_SHARE`` of the
    fresh-against-fresh floor.

    Args:
        reconstruction: ``reconstruction``'s figures.
        figures: ``figures``' figures (with ``latent``, ``sensitivity`` and ``structure``).
        worlds: the dataset's size (caps how many distinct worlds a nearest-world repair can give).
        training_nll: the last epoch's NLL per training world (tells overfit from underfit), if known.
    """
    structure = figures["structure"]
    return (
        _collapse(reconstruction, figures["latent"], training_nll)
        + _inert(figures, worlds)
        + _narrow(structure)
        + _shifted(structure)
        + _uncovered(figures.get("coverage"))
    )


def gate(warnings: list[str], waiver: str | None = None) -> dict:
    """The quality gate's verdict on a generator, from ``diagnose``'s warnings.

    Every warning is a rejection (each flags a generator search cannot use). A rejected generator
    is used only under a ``waiver``, a reason recorded with the verdict: a tiny preset's toy
    budgets, or a user's explicit acceptance.

    Args:
        warnings: ``diagnose``'s one-line warnings.
        waiver: why a generator the gate rejects may be used anyway; None: it may not.

    Returns:
        ``{"verdict": "passed" | "waived" | "rejected", "warnings": [...]}``, with ``"waiver": reason``
        when waived.
    """
    if not warnings:
        return {"verdict": "passed", "warnings": []}
    if waiver:
        return {"verdict": "waived", "warnings": list(warnings), "waiver": waiver}
    return {"verdict": "rejected", "warnings": list(warnings)}


def gate_kinds(warnings: list[str]) -> str:
    """The kinds of ``warnings`` (their text before the first colon: collapsed, overfit, ...), each once, comma-separated."""
    return ", ".join(dict.fromkeys(line.split(":")[0] for line in warnings))


def assess(
    generator: Generator, vae: VAE, dataset: WorldDataset, samples: int, key: jax.Array, waiver: str | None = None, progress: bool = False
) -> dict:
    """``quality.json``: a trained generator's reconstruction on its held-out worlds, ``figures`` over ``samples``
    prior draws (a bar over them with ``progress``), its training record, ``diagnose``'s warnings and the
    ``gate``'s verdict (under ``waiver``)."""
    train, held = split_holdout(len(dataset), vae.config.holdout, vae.config.seed)
    recon = reconstruction(generator, dataset, held, train)
    measured = figures(generator, dataset, samples, key, progress)
    warnings = diagnose(recon, measured, len(dataset), vae.kept["nll"])
    history = vae.history
    return {
        "env": dataset.env,
        "worlds": len(dataset),
        "reconstruction": recon,
        dataset.env: measured,
        "training": {
            "epochs": len(history),
            "kept_epoch": vae.kept_epoch or len(history),
            "kept": vae.kept,
            "final": history[-1],
            "history": history,
        },
        "warnings": warnings,
        "gate": gate(warnings, waiver),
    }
