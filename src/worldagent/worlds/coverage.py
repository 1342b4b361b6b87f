"""Does G(z) cover the env's own generator? Decoded worlds against fresh procedural worlds (issue 48).

The rest of the quality gate (``worlds.quality``) compares G(z) with the training set. This module
compares it with what the training set stands for: the env's procedural generator
(``EnvSpec.generate``), drawn afresh at seeds no dataset world used (``fresh_seeds``), so that a
generator that memorised its dataset gains nothing and one that squeezes the generator's
distribution is seen to.

- ``precision_recall`` (Kynkäänniemi et al. 2019) and ``density_coverage`` (Naeem et al. 2020):
  k-nearest-neighbour manifold estimates, k = 5 as both papers, in the feature space of
  ``FeatureSpace``: the env's descriptors, standardised on the fresh worlds, beside a PCA embedding
  of the worlds' cells fitted on a third range of fresh worlds (fitted on the reference worlds
  themselves, its components would fit their sampling noise and spread them wider than any other
  sample: ued_maze's fresh mazes then scored recall 0.61 against fresh mazes). Precision and
  density: how much of G(z) lies where the generator goes; recall and coverage: how much of the
  generator G(z) reaches.
- ``descriptor_quantiles``: each descriptor's 5/25/50/75/95 % quantiles under G(z), the fresh
  worlds and the dataset, side by side.
- ``parameter_spread``: where the env declares ``EnvSpec.generator_params`` (racing: its 20
  checkpoint draws), each parameter's spread under G(z) against the fresh worlds'.
- ``coverage``: all of it, with the fresh-against-fresh figures at a second, disjoint seed range
  (``floor``: what a perfect generator would score at this sample size). Three ranges of fresh
  worlds in all: reference, floor, embedding basis.

Everything is numpy and depends on the env only through its spec.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import numpy as np

from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.worlds.dataset import WorldDataset, make_dataset

NEIGHBOURS = 5  # k of both papers (Kynkäänniemi et al. 2019 §3; Naeem et al. 2020 §4 recommend 5)
COVERAGE_WORLDS = 1000  # decodes and fresh worlds compared (racing: ~5 s to generate 1,000 fresh tracks on one core)
# Principal components of the cells kept as the world embedding. The descriptors measure what the env's author
# thought mattered; the embedding catches what they did not (where a track bends, where harvest's walls and apples
# are). A handful of components: kNN balls in a few dimensions are well populated by 1,000 points, and racing's
# first 8 components hold most of the footprints' variance; the rest is pixel detail no search targets.
EMBEDDING_DIMS = 8
QUANTILES = (5, 25, 50, 75, 95)
DISTANCE_CHUNK = 256  # rows of a distance matrix computed at once (bounded memory)


# -- the two papers' estimators ---------------------------------------------------------------


def _distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """f64[A, B] Euclidean distances between rows of ``a`` f[A, F] and ``b`` f[B, F] (exact: a duplicate is at 0)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return np.concatenate([np.sqrt(((a[i : i + DISTANCE_CHUNK, None, :] - b[None]) ** 2).sum(-1)) for i in range(0, len(a), DISTANCE_CHUNK)])


def _radii(points: np.ndarray, k: int) -> np.ndarray:
    """f64[N]: each point's distance to its k-th nearest neighbour among the others (itself excluded)."""
    if len(points) <= k:
        raise WorldagentError(f"{len(points)} points cannot give a {k}-th nearest neighbour; compare at least {k + 1} worlds.")
    return np.sort(_distances(points, points), axis=1)[:, k]  # column 0 is the point itself


def precision_recall(real: np.ndarray, fake: np.ndarray, k: int = NEIGHBOURS) -> dict:
    """Improved precision and recall (Kynkäänniemi et al. 2019, "Improved Precision and Recall Metric
    for Assessing Generative Models", NeurIPS).

    Each set's manifold is the union of balls around its points, each reaching the point's k-th
    nearest neighbour in its own set. Precision: the share of ``fake`` inside the real manifold;
    recall: the share of ``real`` inside the fake manifold.

    Args:
        real: f[N, F] features of the reference worlds (fresh procedural worlds).
        fake: f[M, F] features of the generated worlds.
        k: neighbours (the paper's 3-5; 5 here).

    Returns:
        ``{"precision": float, "recall": float}``.
    """
    between = _distances(fake, real)  # [M, N]
    precision = (between <= _radii(real, k)[None, :]).any(axis=1).mean()
    recall = (between <= _radii(fake, k)[:, None]).any(axis=0).mean()
    return {"precision": float(precision), "recall": float(recall)}


def density_coverage(real: np.ndarray, fake: np.ndarray, k: int = NEIGHBOURS) -> dict:
    """Density and coverage (Naeem et al. 2020, "Reliable Fidelity and Diversity Metrics for
    Generative Models", ICML).

    Balls around the real points only (each to its k-th nearest real neighbour), so a few outlying
    fakes cannot inflate the fake manifold. Density: how many real balls hold each fake, over k,
    averaged (about 1 when the two distributions agree; above 1 where fakes crowd dense regions);
    coverage: the share of real points whose ball holds some fake (1 - 2^-k ≈ 0.97 expected for two
    equal-size samples of one distribution).

    Args:
        real: f[N, F] features of the reference worlds.
        fake: f[M, F] features of the generated worlds.
        k: neighbours (5, as the paper).

    Returns:
        ``{"density": float, "coverage": float}``.
    """
    inside = _distances(fake, real) <= _radii(real, k)[None, :]  # [M, N]
    return {"density": float(inside.sum() / (k * len(fake))), "coverage": float(inside.any(axis=0).mean())}


# -- the feature space -------------------------------------------------------------------------


@dataclass(frozen=True)
class FeatureSpace:
    """Descriptors standardised on the reference worlds and cells projected on principal directions of other fresh worlds.

    Attributes:
        names: the descriptors used (those constant on the fresh worlds are left out: they cannot be standardised).
        mean, scale: f64[D] the descriptors' mean and standard deviation on the fresh worlds.
        centre: f64[C] the fresh worlds' mean cells.
        components: f64[m, C] the top principal directions of the fresh worlds' cells.
        embedding_scale: one factor for all m projections, so that the block's total variance
            equals the descriptors' (D, one per standardised descriptor; m when there are none):
            the embedding as a whole weighs as much as all the descriptors together, however many
            components it keeps (weighed per dimension, 8 components of cell noise would drown
            2 descriptors: a scatter maze generator that makes only the quarter of mazes with the
            fewest walls still covered 0.58 of them), and its components keep their relative
            variances (whitening would give the faintest component, mostly pixel noise, the weight
            of the dominant shape).
        explained: the share of the basis cells' variance the m components hold.
    """

    names: tuple[str, ...]
    mean: np.ndarray
    scale: np.ndarray
    centre: np.ndarray
    components: np.ndarray
    embedding_scale: float
    explained: float

    @classmethod
    def fit(cls, descriptors: dict[str, np.ndarray], cells: np.ndarray, basis: np.ndarray | None = None, dims: int = EMBEDDING_DIMS) -> FeatureSpace:
        """The space of the reference worlds: their ``descriptors`` ``{name: f[N]}`` and ``cells`` u8[N, C] (which
        set the scales), projected on the principal directions of ``basis`` u8[N', C], the cells of other worlds
        of the same generator (see the module docstring; None: ``cells`` themselves)."""
        names = tuple(name for name, values in descriptors.items() if np.std(values) > 0)
        values = np.stack([descriptors[name] for name in names], axis=1) if names else np.zeros((len(cells), 0))
        basis = np.asarray(cells if basis is None else basis, np.float64).reshape(len(cells if basis is None else basis), -1)
        centre = basis.mean(axis=0)
        directions, explained = _principal_directions(basis - centre, dims)
        projected = (np.asarray(cells, np.float64).reshape(len(cells), -1) - centre) @ directions.T
        total = float(projected.var(axis=0).sum())
        return cls(
            names=names,
            mean=values.mean(axis=0),
            scale=values.std(axis=0),
            centre=centre,
            components=directions,
            embedding_scale=float(np.sqrt((len(names) or len(directions)) / total)) if len(directions) and total > 0 else 1.0,
            explained=explained,
        )

    def __call__(self, descriptors: dict[str, np.ndarray], cells: np.ndarray) -> np.ndarray:
        """f64[N, D + m]: worlds' features (their ``descriptors`` ``{name: f[N]}`` and ``cells`` u8[N, C])."""
        flat = np.asarray(cells, np.float64).reshape(len(cells), -1)
        described = [(np.asarray(descriptors[name], np.float64) - mean) / scale for name, mean, scale in zip(self.names, self.mean, self.scale)]
        embedded = (flat - self.centre) @ self.components.T * self.embedding_scale
        return np.concatenate([np.stack(described, axis=1) if described else np.zeros((len(flat), 0)), embedded], axis=1)


def _principal_directions(centred: np.ndarray, dims: int) -> tuple[np.ndarray, float]:
    """(f64[m, C] the top m <= ``dims`` principal directions of centred rows f64[N, C], the share of variance they hold).

    From the N x N Gram matrix: with N <= 1,000 rows of up to 4,096 cells, its top eigenvectors cost 0.6 s
    where a full SVD of the rows costs 16 s. Directions of (numerically) zero variance are dropped.
    """
    from scipy.linalg import eigh

    gram = centred @ centred.T
    top = min(dims, len(gram))
    if top == 0:
        return np.zeros((0, centred.shape[1])), 1.0
    values, vectors = eigh(gram, subset_by_index=[len(gram) - top, len(gram) - 1])
    values, vectors = values[::-1], vectors[:, ::-1]  # largest first
    kept = values > 1e-12 * max(values.max(initial=0.0), 1.0)
    values, vectors = values[kept], vectors[:, kept]
    directions = (vectors.T @ centred) / np.sqrt(values)[:, None]  # unit rows: X^T u / s
    total = float(np.trace(gram))
    return directions, float(values.sum() / total) if total > 0 else 1.0


def describe(spec, worlds, count: int) -> dict[str, np.ndarray]:
    """``{descriptor: f64[count]}`` of the first ``count`` worlds of a batch (host-side, one by one)."""
    from worldagent.worlds.quality import _each

    unbatched = list(_each(worlds, count))
    return {name: np.array([fn(world) for world in unbatched], np.float64) for name, fn in spec.metrics.descriptors.items()}


def _take(worlds, count: int):
    """The first ``count`` worlds of a batch."""
    return jax.tree_util.tree_map(lambda leaf: np.asarray(leaf)[:count], worlds)


# -- fresh worlds ------------------------------------------------------------------------------


def fresh_seeds(dataset_seeds: np.ndarray, count: int, offset: int = 0) -> np.ndarray:
    """int64[count]: seeds no dataset world used, ``max(dataset seeds) + 1 + offset`` onwards.

    Starting past the dataset's largest seed keeps them disjoint from every dataset seed whether
    the dataset's seeds are contiguous (``make_dataset``: seed, seed + 1, ...) or not; a second
    range at ``offset = count`` gives the fresh-against-fresh floor.
    """
    start = int(np.max(dataset_seeds)) + 1 + int(offset) if len(dataset_seeds) else int(offset)
    return start + np.arange(int(count), dtype=np.int64)


def fresh_worlds(spec, dataset: WorldDataset, count: int, offset: int = 0) -> WorldDataset:
    """``count`` worlds of the env's own generator at ``fresh_seeds(dataset.seeds, count, offset)``."""
    return make_dataset(spec, count, int(fresh_seeds(dataset.seeds, 1, offset)[0]), progress=False)


# -- side by side ------------------------------------------------------------------------------


def descriptor_quantiles(sides: dict[str, dict[str, np.ndarray]]) -> dict:
    """``{descriptor: {side: [q5, q25, q50, q75, q95]}}`` for ``sides`` ``{side: {descriptor: f[N]}}``."""
    names = next(iter(sides.values())).keys()
    return {name: {side: np.percentile(values[name], QUANTILES).tolist() for side, values in sides.items()} for name in names}


def parameter_spread(generated: dict[str, np.ndarray], fresh: dict[str, np.ndarray]) -> dict:
    """Each generator parameter's mean and std under G(z) and on the fresh worlds, and the std ratio.

    Args:
        generated, fresh: ``{parameter: f[N]}`` (``EnvSpec.generator_params`` of each side).

    Returns:
        ``{"parameters": {name: {"generator_mean", "fresh_mean", "generator_std", "fresh_std", "std_ratio"}},
        "min_std_ratio", "median_std_ratio"}`` (ratios None where the fresh std is 0).
    """
    rows = {}
    for name, ours in generated.items():
        theirs = np.asarray(fresh[name], np.float64)
        ours = np.asarray(ours, np.float64)
        ratio = float(ours.std() / theirs.std()) if theirs.std() > 0 else None
        rows[name] = {
            "generator_mean": float(ours.mean()),
            "fresh_mean": float(theirs.mean()),
            "generator_std": float(ours.std()),
            "fresh_std": float(theirs.std()),
            "std_ratio": ratio,
        }
    ratios = [row["std_ratio"] for row in rows.values() if row["std_ratio"] is not None]
    return {
        "parameters": rows,
        "min_std_ratio": float(min(ratios)) if ratios else None,
        "median_std_ratio": float(np.median(ratios)) if ratios else None,
    }


def _scores(real: np.ndarray, fake: np.ndarray) -> dict:
    return {**precision_recall(real, fake), **density_coverage(real, fake)}


def coverage(spec, generated, count: int, dataset: WorldDataset, floor: bool = True) -> dict:
    """G(z) against fresh worlds of the env's generator: precision, recall, density, coverage, quantiles.

    Args:
        spec: the env's spec (or name).
        generated: batched G(z) worlds (at least ``count``).
        count: worlds of each side compared (``NEIGHBOURS`` + 1 at least).
        dataset: G's training dataset (its seeds are avoided; its worlds give the quantiles' third column).
        floor: also score fresh worlds at a second, disjoint seed range against the first (what a
            generator identical to the env's would score at this ``count``).

    Returns:
        ``precision``, ``recall``, ``density``, ``coverage`` (floats), ``floor`` (the same four,
        fresh against fresh, or None), ``quantiles`` (``descriptor_quantiles``: ``generator``,
        ``fresh``, ``dataset``), ``generator_params`` (``parameter_spread``, or None where the env
        declares none), ``features`` (the descriptors used, the embedding's dimensions and
        explained variance), ``k``, ``worlds`` (count) and ``fresh_seeds`` ([first, last] of the
        reference worlds; the floor's and the embedding's ranges follow, ``count`` seeds each).
    """
    spec = registry.get(spec)
    count = int(count)
    if count <= NEIGHBOURS:
        raise WorldagentError(f"coverage compares {count} worlds; draw more than {NEIGHBOURS} (its k-th nearest neighbours need them).")
    fresh = fresh_worlds(spec, dataset, count)
    generated = _take(generated, count)
    ours, theirs = describe(spec, generated, count), describe(spec, fresh.worlds, count)
    reference = describe(spec, dataset.worlds, min(count, len(dataset)))
    space = FeatureSpace.fit(theirs, fresh.cells, basis=fresh_worlds(spec, dataset, count, offset=2 * count).cells)
    real = space(theirs, fresh.cells)
    result = _scores(real, space(ours, np.asarray(spec.cells(generated), np.uint8)))
    if floor:
        second = fresh_worlds(spec, dataset, count, offset=count)
        result["floor"] = _scores(real, space(describe(spec, second.worlds, count), second.cells))
    else:
        result["floor"] = None
    sides = {"generator": ours, "fresh": theirs, "dataset": reference}
    params = None
    if spec.generator_params is not None:
        params = parameter_spread(spec.generator_params(generated), spec.generator_params(fresh.worlds))
    return {
        **result,
        "quantiles": descriptor_quantiles(sides) if spec.metrics.descriptors else {},
        "generator_params": params,
        "features": {"descriptors": list(space.names), "embedding_dims": int(len(space.components)), "explained_variance": space.explained},
        "k": NEIGHBOURS,
        "worlds": count,
        "fresh_seeds": [int(fresh.seeds[0]), int(fresh.seeds[-1])],
    }
