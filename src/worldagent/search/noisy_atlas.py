"""Atlases that survive noise while they search (issue 50; Flageat & Cully 2023, "Uncertain Quality-Diversity").

- ``CorrectedQD``: CMA-ME for most of the budget, then its elites re-evaluated, each cell keeping the
  elite with the best mean over its evaluations.
- ``AdaptiveQD``: adaptive sampling: every generation re-evaluates a few elites, and a challenger takes
  a cell only once it has as many evaluations as the elite it would replace (up to ``CHALLENGE_EVALUATIONS``).
- ``noisy_atlas_optimiser``: either, on ``search.atlas``'s grid, with the campaign's record.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict
from typing import Any

import numpy as np

from worldagent.errors import WorldagentError
from worldagent.search.atlas import Grid, QDConfig, QDOptimiser, cell_of, check_descriptors, describer, grid_ranges

ADAPTIVE_REEVALUATIONS = 3  # re-evaluation slots per adaptive-sampling generation (18 offspring + 3)
CHALLENGE_EVALUATIONS = 4  # a challenger replaces an elite once it has min(this, the elite's) evaluations


class CorrectedQD(QDOptimiser):
    """CMA-ME for ``search_generations`` generations, then a corrected archive: every later generation re-asks
    the elites with the best pooled means (each elite: the cell's best world by the search's single scores), so a
    lucky elite is played again and falls back, and the next is re-asked. ``elites()`` is the corrected archive.
    """

    name = "cma-me-corrected"

    def __init__(self, dim, maximize, seed, grid: Grid, describe: Callable, config: QDConfig = QDConfig(), search_generations: int = 1):
        super().__init__(dim, maximize, seed, grid, describe, config)
        from worldagent.search.optimisers import Pooled

        if search_generations < 1:
            raise WorldagentError(f"search_generations={search_generations}; search at least one generation before re-evaluating.")
        self.search_generations, self.generation = int(search_generations), 0
        self.pooled = Pooled(dim)
        self.cells: dict[int, bytes] = {}  # cell -> its elite's latent key
        self.first: dict[bytes, float] = {}  # a latent's first score ("lower is better")
        self._pending: np.ndarray | None = None

    def ask(self, n: int) -> np.ndarray:
        if n != self._size:
            raise WorldagentError(f"{self.name} asks a whole generation of {self._size}; asked for {n}.")
        if self._pending is not None:
            raise WorldagentError(f"{self.name}: tell() the scores of the last generation before asking again.")
        self._pending = self.offspring() if self.generation < self.search_generations else self.best_elites(n)
        return self._pending.copy()

    def offspring(self) -> np.ndarray:
        return np.asarray(self.scheduler.ask(), np.float64)

    def best_elites(self, n: int) -> np.ndarray:
        """f64[n, dim]: the elites with the best pooled means (cycled when there are fewer than ``n``)."""
        order = {key: i for i, key in enumerate(self.pooled.latents)}  # the earliest first on ties
        elites = sorted(self.cells.values(), key=lambda key: (self.pooled.sums[key] / self.pooled.counts[key], order[key]))
        if not elites:
            raise WorldagentError(f"{self.name}: no elite to re-evaluate; search at least one generation first.")
        latents = [self.pooled.latents[k] for k in elites]
        return np.array([latents[i % len(latents)] for i in range(n)], np.float64)

    def tell(self, z: np.ndarray, scores: np.ndarray) -> None:
        z, scores = self._checked(z, scores)
        if self._pending is None or not np.array_equal(z, self._pending):
            raise WorldagentError(f"{self.name} must be told the scores of exactly the generation it asked for.")
        minimised = self._minimised(scores)
        if self.generation < self.search_generations:
            self.place(z, minimised)
        self.pooled.add(z, minimised)
        self._pending = None
        self.generation += 1

    def place(self, z: np.ndarray, minimised: np.ndarray) -> None:
        """Tell the emitters a generation of offspring and keep each cell's best by these single scores."""
        from worldagent.search.optimisers import latent_key

        measures = self.describe(z)
        self.scheduler.tell(-minimised, measures)  # pyribs maximises
        for latent, score, cell in zip(z, minimised, cell_of(self.grid, measures)):
            key = latent_key(latent)
            self.first.setdefault(key, float(score))
            elite = self.cells.get(int(cell))
            if elite is None or score < self.first[elite]:
                self.cells[int(cell)] = key

    def elites(self) -> dict[int, tuple[np.ndarray, float, int]]:
        """{cell: (latent, pooled mean in the search's direction, evaluations)}: the archive as corrected so far."""
        rows = {}
        for cell, key in sorted(self.cells.items()):
            mean = self.pooled.sums[key] / self.pooled.counts[key]
            rows[cell] = (self.pooled.latents[key].copy(), -mean if self.maximize else mean, self.pooled.counts[key])
        return rows


class AdaptiveQD(CorrectedQD):
    """CMA-ME with adaptive sampling (Justesen et al. 2019, one of Uncertain QD's methods): each generation is the
    emitters' offspring and ``ADAPTIVE_REEVALUATIONS`` re-evaluations. An offspring that lands in an empty cell is
    its elite; one whose score beats the cell's elite's pooled mean is a challenger, re-asked until it has
    ``min(CHALLENGE_EVALUATIONS, the elite's evaluations)`` evaluations, and takes the cell only if its pooled
    mean still beats the elite's. Slots no challenger needs re-ask the elites with the best pooled means.
    ``config.emitters × config.batch`` offspring (default 3 × 6: 21 a generation with the re-evaluations).
    """

    name = "cma-me-adaptive"

    def __init__(self, dim, maximize, seed, grid: Grid, describe: Callable, config: QDConfig = QDConfig(batch=6)):
        super().__init__(dim, maximize, seed, grid, describe, config, search_generations=1)
        self._offspring = self._size
        self._size = self._offspring + ADAPTIVE_REEVALUATIONS
        self.challengers: list[tuple[int, bytes]] = []  # (cell, latent key), oldest first

    def ask(self, n: int) -> np.ndarray:
        if n != self._size:
            raise WorldagentError(f"{self.name} asks a whole generation of {self._size}; asked for {n}.")
        if self._pending is not None:
            raise WorldagentError(f"{self.name}: tell() the scores of the last generation before asking again.")
        fresh = self.offspring()
        again = [self.pooled.latents[key] for _, key in self.challengers[:ADAPTIVE_REEVALUATIONS]]
        if len(again) < ADAPTIVE_REEVALUATIONS:
            rest = ADAPTIVE_REEVALUATIONS - len(again)
            again += list(self.best_elites(rest) if self.cells else fresh[:rest])  # nothing scored yet: the round's own
        self._pending = np.vstack([fresh, np.asarray(again, np.float64).reshape(-1, self.dim)])
        return self._pending.copy()

    def tell(self, z: np.ndarray, scores: np.ndarray) -> None:
        from worldagent.search.optimisers import latent_key

        z, scores = self._checked(z, scores)
        if self._pending is None or not np.array_equal(z, self._pending):
            raise WorldagentError(f"{self.name} must be told the scores of exactly the generation it asked for.")
        minimised = self._minimised(scores)
        fresh = slice(0, self._offspring)
        self.pooled.add(z, minimised)
        measures = self.describe(z[fresh])
        self.scheduler.tell(-minimised[fresh], measures)
        for latent, score, cell in zip(z[fresh], minimised[fresh], cell_of(self.grid, measures)):
            key, cell = latent_key(latent), int(cell)
            elite = self.cells.get(cell)
            if elite is None:
                self.cells[cell] = key
            elif key != elite and score < self.mean(elite):
                self.challengers.append((cell, key))
        self.settle()
        self._pending = None
        self.generation += 1

    def mean(self, key: bytes) -> float:
        return self.pooled.sums[key] / self.pooled.counts[key]

    def settle(self) -> None:
        """Decide every challenger that has enough evaluations; drop those that no longer beat their elite."""
        waiting = []
        for cell, key in self.challengers:
            elite = self.cells[cell]
            if self.mean(key) >= self.mean(elite):
                continue  # fell back: the elite stays
            if self.pooled.counts[key] >= min(CHALLENGE_EVALUATIONS, self.pooled.counts[elite]):
                self.cells[cell] = key
            else:
                waiting.append((cell, key))
        self.challengers = waiting


def noisy_atlas_optimiser(
    spec: Any, generator: Any, maximize: bool, seed: int, budget: int, method: str, descriptors: Sequence[str] | None = None, cells: int = 10
) -> tuple[QDOptimiser, dict]:
    """``atlas_optimiser``'s grid with a noise-aware atlas: ``method`` "corrected" (CMA-ME for 70% of ``budget``,
    whole generations, then its elites re-evaluated) or "adaptive" (adaptive sampling); and the campaign's record."""
    names, shape = check_descriptors(spec, descriptors, cells, budget)
    describe = describer(spec, generator, names)
    grid = Grid(names, shape, grid_ranges(describe, generator.latent_dim, names, seed))
    if method == "corrected":
        config = QDConfig()
        searching = max(1, int(0.7 * budget) // (config.emitters * config.batch))
        optimiser: QDOptimiser = CorrectedQD(generator.latent_dim, maximize, seed, grid, describe, config, searching)
        record = {**asdict(config), "method": method, "search_generations": searching}
    elif method == "adaptive":
        config = QDConfig(batch=6)
        optimiser = AdaptiveQD(generator.latent_dim, maximize, seed, grid, describe, config)
        record = {**asdict(config), "method": method, "reevaluations": ADAPTIVE_REEVALUATIONS, "challenge": CHALLENGE_EVALUATIONS}
    else:
        raise WorldagentError(f"unknown noise-aware atlas {method!r}; use corrected or adaptive.")
    return optimiser, {"atlas": {"grid": grid.record(), **record}}
