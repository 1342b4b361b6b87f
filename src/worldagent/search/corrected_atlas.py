"""The **corrected archive** of Uncertain Quality-Diversity (Flageat & Cully 2023): every elite of an atlas
(the best world of a filled cell, ``search.atlas``) replayed on fresh episodes (``analysis.confirm``,
``ELITE_REPEATS`` each) and re-scored by them.

An elite is the best of many noisy scores, so the found archive is biased the way of the search; the
corrected one is not. Descriptors are a function of the world, not of the episodes, so no elite changes
cell: coverage stays (a cell whose fresh episodes give no finite value drops out), the QD-score (same
offset) and the failing cells change. A cell is *confirmed failing* when its elite's confirmed interval
is beyond the failure threshold (``ConfirmedWorld.holds``); found-failing cells that are not are
reported as no longer failing. Counts of failing worlds count distinct repaired worlds.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from worldagent.errors import WorldagentError
from worldagent.search.atlas import Archive, Grid, StoredAtlas
from worldagent.store import Evaluation, world_digest


def elites_of(evaluations: Sequence[Evaluation], archive: Archive) -> list[Evaluation]:
    """The best evaluation of each filled cell, in the archive's order."""
    return [evaluations[int(i)] for i in archive.best]


def corrected_archive(archive: Archive, confirmed: Sequence[Any], metric: str) -> Archive:
    """``archive`` re-scored by its elites' confirmations (``ConfirmedWorld`` s, one per filled cell, in
    order): each cell keeps its elite (descriptors do not depend on episodes) with the confirmed mean of
    ``metric``; cells whose fresh episodes give no finite value drop out."""
    if len(confirmed) != len(archive.cells):
        raise WorldagentError(f"{len(confirmed)} confirmed elites for an archive of {len(archive.cells)} cells; confirm every elite.")
    scores = np.array([c.confirmed(metric).mean for c in confirmed], np.float64)
    keep = np.flatnonzero(np.isfinite(scores))
    return Archive(archive.cells[keep], archive.best[keep], scores[keep], archive.measures[keep])


def failing_worlds(confirmed: Sequence[Any], which: Sequence[bool]) -> int:
    """How many distinct repaired worlds the confirmed elites marked by ``which`` are."""
    return len({c.digest for c, bad in zip(confirmed, which) if bad})


def corrected_summary(
    grid: Grid, archive: Archive, confirmed: Sequence[Any], metric: str, offset: float, maximize: bool, selection: Any = None
) -> dict:
    """Found beside corrected: coverage, QD-score (``offset``: the found archive's, so the two compare) and,
    with ``selection`` (the failure), failing cells and distinct failing worlds.

    Args:
        grid, archive: the found archive (``archive_of``); confirmed: ``ConfirmedWorld`` per filled cell, in order.
        metric: the archive's (canonical) metric; maximize: its direction.
        selection: the failure event (``events.parse_selection``) or None.

    Returns:
        {"repeats", "elites", "distinct_worlds", "episodes", "found": {"coverage", "qd_score"[, "failing_cells",
        "failing_worlds"]}, "confirmed": the same of the corrected archive, "cells": one row per filled cell
        ({"cell", descriptors, ``ConfirmedWorld.as_dict``}), "no_longer_failing": cells found failing but not
        confirmed failing}.
    """
    corrected = corrected_archive(archive, confirmed, metric)
    distinct = {c.digest: c for c in confirmed}
    summary: dict = {
        "metric": metric,
        "repeats": max((c.repeats for c in confirmed), default=0),
        "elites": len(confirmed),
        "distinct_worlds": len(distinct),
        "episodes": sum(c.repeats for c in distinct.values()),
        "found": {"coverage": archive.coverage(grid), "qd_score": archive.qd_score(offset, maximize)},
        "confirmed": {"coverage": corrected.coverage(grid), "qd_score": corrected.qd_score(offset, maximize)},
    }
    metrics = [metric, *([] if selection is None else [m for m in selection.metrics if m != metric])]
    cells = [
        {"cell": int(cell), **dict(zip(grid.descriptors, map(float, archive.measures[i]))), **c.as_dict(metrics, selection)}
        for i, (cell, c) in enumerate(zip(archive.cells, confirmed))
    ]
    if selection is not None:
        found = [bool(selection.mask([c.selected])[0]) for c in confirmed]
        holds = [c.holds(selection) for c in confirmed]
        summary["event"] = selection.describe()
        summary["found"] |= {"failing_cells": int(sum(found)), "failing_worlds": failing_worlds(confirmed, found)}
        summary["confirmed"] |= {"failing_cells": int(sum(holds)), "failing_worlds": failing_worlds(confirmed, holds)}
        summary["no_longer_failing"] = [row["cell"] for row, bad, held in zip(cells, found, holds) if bad and not held]
    summary["cells"] = cells
    return summary


def confirm_elites(
    store: Any, setup: Any, found: dict, metric: str, maximize: bool, selection: Any = None, *, repeats: int, seed: int, progress: bool = True
) -> dict | None:
    """Every elite of an atlas (one campaign's ``experiments.atlas_summary`` entry) confirmed on ``repeats`` fresh
    episodes (``analysis.confirm``; stored, resumable, named ``atlas:<campaign>``), and ``corrected_summary``.
    None when ``repeats`` is 0 (skipped) or the archive is empty."""
    from worldagent.analysis.confirm import confirm

    archive = found["archive"]
    if repeats == 0 or not len(archive.cells):
        return None
    elites = elites_of(found["evaluations"], archive)
    confirmed = confirm(store, setup, elites, name=f"atlas:{elites[0].campaign}", repeats=repeats, seed=seed, progress=progress)
    return corrected_summary(found["grid"], archive, confirmed, metric, found["qd_offset"], maximize, selection)


def stored_elites(store: Any, atlas: StoredAtlas, agent: str, seed: int, repeats: int) -> list[Any] | None:
    """The confirmations of ``atlas``'s elites already in ``store`` (for ``analysis.confirm.agent_key`` ``agent``,
    ``seed`` and ``repeats``) as ``ConfirmedWorld`` s; None unless every elite has one. Needs no agent."""
    from worldagent.analysis.confirm import ConfirmedWorld, confirmation_seed

    done = {c.world: c for c in store.confirmations(agent, atlas.campaign.env) if c.seed == int(seed) and c.repeats == int(repeats)}
    found = []
    for elite in elites_of(atlas.evaluations, atlas.archive):
        digest = world_digest(elite.world)
        if digest not in done:
            return None
        found.append(ConfirmedWorld(elite, digest, done[digest].episodes, confirmation_seed(seed, digest)))
    return found


def cell_line(row: dict, descriptors: Sequence[str], metric: str) -> str:
    """ "cell 12 (total_curvature 5.2, sharpest_corner 1.1): crash_rate found 0.75 (the selection's, 8 episodes);
    confirmed 0.41 [0.29, 0.53] (32 fresh episodes)" of a ``corrected_summary`` cell row."""
    found, confirmed = row["found"][metric], row["confirmed"][metric]
    where = ", ".join(f"{name} {row[name]:.3g}" for name in descriptors)
    return (
        f"cell {row['cell']} ({where}): {metric} found {found['mean']:.4g} (the selection's, {found['episodes']} episodes); "
        f"confirmed {confirmed['mean']:.4g} [{confirmed['low']:.4g}, {confirmed['high']:.4g}] ({confirmed['episodes']} fresh episodes)"
    )
