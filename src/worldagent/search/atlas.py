"""Quality-diversity search over worlds: a grid archive over world descriptors (pyribs).

The paper finds *the* worst world; a failure atlas keeps the worst world of every *kind* of
world. Each world has descriptors (``EnvSpec.metrics.descriptors``: e.g. a track's total
curvature and sharpest corner); a grid over two or three of them is the archive, and each cell
keeps the world with the best objective (the lowest return, when looking for failures).

- ``Grid``: which descriptors, how many cells each, and their ranges (from G(z) samples of the
  prior, so the grid covers the worlds the generator makes).
- ``QDOptimiser``: CMA-ME (pyribs' ``EvolutionStrategyEmitter`` with improvement ranking)
  behind the same ask/tell as the other optimisers, so a campaign stores, resumes and farms it
  out like any other. It is deterministic given its seed; descriptors are a function of the
  latent (G(z) then the spec's descriptor functions), so a replay rebuilds the same archive.
- ``archive_of``: any campaign's evaluations (QD, CMA-ES, random) placed on a grid, so that
  QD-score, coverage and the number of distinct failing worlds compare on equal terms.
- ``StoredAtlas`` / ``read_atlas``: an atlas campaign read back from the store, with no agent.

The corrected archive (every elite confirmed on fresh episodes) is ``search.corrected_atlas``; atlases
that re-evaluate while they search (Uncertain Quality-Diversity) are ``search.noisy_atlas``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.errors import WorldagentError
from worldagent.search.optimisers import Optimiser
from worldagent.store import world_digest

RANGE_SAMPLES = 512  # prior latents whose descriptors set the grid's ranges


@dataclass(frozen=True)
class Grid:
    """The archive's layout.

    Attributes:
        descriptors: names in ``spec.metrics.descriptors`` (2 or 3).
        cells: cells along each descriptor.
        ranges: (low, high) of each descriptor; values outside land in the edge cells.
    """

    descriptors: tuple[str, ...]
    cells: tuple[int, ...]
    ranges: tuple[tuple[float, float], ...]

    def record(self) -> dict:
        """As kept in the campaign's config."""
        return {k: [list(r) for r in v] if k == "ranges" else list(v) for k, v in asdict(self).items()}

    @property
    def size(self) -> int:
        return int(np.prod(self.cells))


@dataclass(frozen=True)
class QDConfig:
    """CMA-ME settings: ``emitters`` CMA-ES emitters of ``batch`` latents each per generation
    (3 × 7 = 21, the paper's CMA-ES population), from mean 0 with step ``sigma0``, in ``|z_i| <= bound``."""

    emitters: int = 3
    batch: int = 7
    sigma0: float = 1.0
    bound: float = 3.0


def check_descriptors(spec: Any, names: Sequence[str] | None, cells: int, budget: int) -> tuple[tuple[str, ...], tuple[int, ...]]:
    """The descriptor names (default: the spec's) and cells per descriptor, refused with one line when unusable."""
    names = tuple(names or spec.metrics.default_descriptors)
    known = ", ".join(spec.metrics.descriptors) or "none"
    if not names:
        raise WorldagentError(f"{spec.name} names no default descriptors; pass --descriptors from: {known}.")
    for name in names:
        if name not in spec.metrics.descriptors:
            raise WorldagentError(f"unknown descriptor {name!r} for {spec.name}; use some of: {known}.")
    if not 1 <= len(names) <= 3 or len(set(names)) != len(names):
        raise WorldagentError(f"descriptors {', '.join(names)}: pick 1 to 3 different ones.")
    if cells < 2:
        raise WorldagentError(f"--cells {cells}; an archive needs at least 2 cells per descriptor.")
    if budget < cells ** len(names):
        raise WorldagentError(f"--budget {budget} is smaller than the grid's {cells ** len(names)} cells; raise the budget or lower --cells.")
    return names, (int(cells),) * len(names)


def describer(spec: Any, generator: Any, names: Sequence[str], chunk: int = 21) -> Callable[[np.ndarray], np.ndarray]:
    """``describe(z[n, dim]) -> f64[n, k]``: the descriptors of the worlds G(z).

    G runs on ``chunk`` latents at a time (the last chunk padded), the batch a generation
    decodes, so it compiles once however many latents are described.
    """
    from worldagent.search.objectives import generate

    functions = [spec.metrics.descriptors[name] for name in names]

    def describe(z: np.ndarray) -> np.ndarray:
        z = np.asarray(z, np.float32)
        rows = []
        for start in range(0, len(z), chunk):
            part = z[start : start + chunk]
            padded = np.concatenate([part, np.zeros((chunk - len(part), z.shape[1]), np.float32)])
            worlds = jax.tree_util.tree_map(np.asarray, generate(generator, jnp.asarray(padded)))
            rows += [[f(jax.tree_util.tree_map(lambda leaf, i=i: leaf[i], worlds)) for f in functions] for i in range(len(part))]
        return np.array(rows, np.float64).reshape(len(z), len(functions))

    return describe


def grid_ranges(describe: Callable, dim: int, names: Sequence[str], seed: int = 0) -> tuple[tuple[float, float], ...]:
    """(low, high) of each descriptor over ``RANGE_SAMPLES`` prior latents; a constant one is refused."""
    z = np.random.default_rng([seed, 7]).standard_normal((RANGE_SAMPLES, dim))
    values = describe(z)
    low, high = values.min(axis=0), values.max(axis=0)
    for name, lo, hi in zip(names, low, high):
        if not hi > lo:
            raise WorldagentError(
                f"descriptor {name!r} is {lo:g} on all {RANGE_SAMPLES} worlds G(z) decoded from prior latents; pick one that varies "
                "(`worldagent check ENV --generator DIR` checks every descriptor on decoded worlds; `generator report DIR` says if G(z) collapsed)."
            )
    return tuple((float(lo), float(hi)) for lo, hi in zip(low, high))


class QDOptimiser(Optimiser):
    """CMA-ME over a ``Grid`` (see the module docstring); ``describe`` gives the descriptors of latents."""

    name = "cma-me"
    whole_generations = True

    def __init__(self, dim: int, maximize: bool, seed: int, grid: Grid, describe: Callable, config: QDConfig = QDConfig()):
        super().__init__(dim, maximize, seed)
        from ribs.archives import GridArchive
        from ribs.emitters import EvolutionStrategyEmitter
        from ribs.schedulers import Scheduler

        self.describe, self.grid = describe, grid
        self.archive = GridArchive(solution_dim=dim, dims=grid.cells, ranges=grid.ranges, seed=seed)
        bounds = [(-config.bound, config.bound)] * dim if config.bound > 0 else None
        emitters = [
            EvolutionStrategyEmitter(
                self.archive, x0=np.zeros(dim), sigma0=config.sigma0, ranker="2imp", bounds=bounds, batch_size=config.batch, seed=seed * 1009 + i + 1
            )
            for i in range(config.emitters)
        ]
        self.scheduler = Scheduler(self.archive, emitters)
        self._size = config.emitters * config.batch

    @property
    def batch_size(self) -> int:
        return self._size

    def ask(self, n: int) -> np.ndarray:
        if n != self._size:
            raise WorldagentError(f"CMA-ME asks a whole generation of {self._size}; asked for {n}.")
        return np.asarray(self.scheduler.ask(), np.float64)

    def tell(self, z: np.ndarray, scores: np.ndarray) -> None:
        z, scores = self._checked(z, scores)
        self.scheduler.tell(-self._minimised(scores), self.describe(z))  # pyribs maximises


def atlas_optimiser(
    spec: Any, generator: Any, maximize: bool, seed: int, budget: int, descriptors: Sequence[str] | None = None, cells: int = 10
) -> tuple[QDOptimiser, dict]:
    """A CMA-ME optimiser over a grid of ``spec``'s descriptors (default: the spec's), and what its
    campaign records (``CampaignSpec.extra``: the grid and the emitters' settings); bad input is refused in one line."""
    names, shape = check_descriptors(spec, descriptors, cells, budget)
    describe = describer(spec, generator, names)
    grid = Grid(names, shape, grid_ranges(describe, generator.latent_dim, names, seed))
    config = QDConfig()
    optimiser = QDOptimiser(generator.latent_dim, maximize, seed, grid, describe, config)
    return optimiser, {"atlas": {"grid": grid.record(), **asdict(config)}}


@dataclass(frozen=True)
class Archive:
    """Evaluations placed on a grid: the best world of each cell.

    Attributes:
        cells: int[m] flat indices of the filled cells.
        best: the index (into the evaluations given) of each filled cell's best world.
        scores: f64[m] their scores; measures: f64[m, k] their descriptors.
    """

    cells: np.ndarray
    best: np.ndarray
    scores: np.ndarray
    measures: np.ndarray

    def coverage(self, grid: Grid) -> float:
        return len(self.cells) / grid.size

    def qd_score(self, offset: float, maximize: bool) -> float:
        """Σ over filled cells of how far the cell's best is past ``offset`` (the worst score compared)."""
        return float(np.sum(self.scores - offset if maximize else offset - self.scores))


def qd_offset(scores: np.ndarray, maximize: bool) -> float:
    """The QD-score's offset: the worst finite score among those compared (0 when none is finite)."""
    finite = np.asarray(scores, np.float64)
    finite = finite[np.isfinite(finite)]
    return float(finite.min() if maximize else finite.max()) if finite.size else 0.0


def distinct_picks(archive: Any, maximize: bool, count: int) -> list[int]:
    """Up to ``count`` archive entries: the most extreme first, then each farthest (in normalised
    descriptor space) from those already picked, among the most extreme half."""
    if not len(archive.scores):
        return []
    order = np.argsort(-archive.scores if maximize else archive.scores)
    pool = order[: max(count, len(order) // 2)]
    span = np.ptp(archive.measures, axis=0)
    measures = archive.measures / np.where(span > 0, span, 1.0)
    picks = [int(pool[0])]
    while len(picks) < min(count, len(pool)):
        distance = np.min(np.linalg.norm(measures[pool][:, None] - measures[picks][None], axis=-1), axis=1)
        picks.append(int(pool[int(np.argmax(distance))]))
    return picks


def cell_of(grid: Grid, measures: np.ndarray) -> np.ndarray:
    """int[n]: the flat grid cell of each row of descriptors (outside the ranges: the edge cell)."""
    index = []
    for k, (cells, (low, high)) in enumerate(zip(grid.cells, grid.ranges)):
        position = np.floor((measures[:, k] - low) / (high - low) * cells).astype(int)
        index.append(np.clip(position, 0, cells - 1))
    return np.ravel_multi_index(tuple(index), grid.cells)


def archive_of(grid: Grid, scores: np.ndarray, measures: np.ndarray, maximize: bool) -> Archive:
    """The best (highest when ``maximize``) finite score of each filled cell; the earliest on ties."""
    scores, measures = np.asarray(scores, np.float64), np.asarray(measures, np.float64)
    keep = np.flatnonzero(np.isfinite(scores))
    cells = cell_of(grid, measures[keep]) if len(keep) else np.zeros(0, int)
    best: dict[int, int] = {}
    for cell, i in zip(cells, keep):
        current = best.get(cell)
        if current is None or (scores[i] > scores[current] if maximize else scores[i] < scores[current]):
            best[int(cell)] = int(i)
    filled = np.array(sorted(best), int)
    picks = np.array([best[c] for c in filled], int)
    return Archive(filled, picks, scores[picks] if len(picks) else np.zeros(0), measures[picks] if len(picks) else np.zeros((0, len(grid.cells))))


def distinct_count(worlds: Sequence[dict[str, np.ndarray]]) -> int:
    """How many different worlds (after repair) ``worlds`` holds."""
    return len({world_digest(w) for w in worlds})


@dataclass(frozen=True)
class StoredAtlas:
    """An atlas read back from a run store (``read_atlas``).

    Attributes:
        campaign: the store's ``Campaign``.
        grid: the archive's layout, as the campaign recorded it.
        evaluations: every evaluated world, in order, with its stored world.
        measures: f64[n, k] each evaluated world's descriptors.
        archive: the best world of each filled cell (indices into ``evaluations``).
    """

    campaign: Any
    grid: Grid
    evaluations: list
    measures: np.ndarray
    archive: Archive

    @property
    def maximize(self) -> bool:
        return bool(self.campaign.maximize)

    def cell_table(self) -> list[dict]:
        """One row per filled cell: its flat index, the descriptors and score of its best world, and where that world is stored."""
        return [
            {
                "cell": int(cell),
                **dict(zip(self.grid.descriptors, map(float, self.archive.measures[i]))),
                "score": float(self.archive.scores[i]),
                "generation": self.evaluations[int(self.archive.best[i])].generation,
                "slot": self.evaluations[int(self.archive.best[i])].slot,
            }
            for i, cell in enumerate(self.archive.cells)
        ]


def atlas_names(store: Any) -> list[str]:
    """The store's atlas campaigns (those that recorded a grid), in the order they were made."""
    return [c.name for c in store.campaigns() if "atlas" in c.config]


def read_atlas(store: Any, name: str) -> StoredAtlas:
    """Load atlas campaign ``name`` from a ``RunStore``: its grid, worlds, descriptors and archive.

    Needs no agent and no generator: descriptors are computed from the stored worlds (those G(z)
    made), so the archive equals the one the search built.

    Example::

        with RunStore("runs/atlas") as store:
            atlas = read_atlas(store, atlas_names(store)[0])
            print(atlas.archive.coverage(atlas.grid), atlas.cell_table()[:3])
    """
    from worldagent.envs import registry

    campaign = store.campaign(name)
    if campaign is None or "atlas" not in campaign.config:
        known = ", ".join(atlas_names(store)) or "none"
        raise WorldagentError(f"{name!r} is not an atlas campaign of {store.path}; atlases there: {known}.")
    recorded = campaign.config["atlas"]["grid"]
    grid = Grid(tuple(recorded["descriptors"]), tuple(recorded["cells"]), tuple(tuple(r) for r in recorded["ranges"]))
    spec = registry.get(campaign.env)
    evaluations = store.evaluations(name, with_worlds=True)
    functions = [spec.metrics.descriptors[d] for d in grid.descriptors]
    measures = np.array([[f(spec.world_from_arrays(e.world)) for f in functions] for e in evaluations], np.float64).reshape(-1, len(functions))
    scores = np.array([e.score for e in evaluations], np.float64)
    return StoredAtlas(campaign, grid, evaluations, measures, archive_of(grid, scores, measures, bool(campaign.maximize)))
