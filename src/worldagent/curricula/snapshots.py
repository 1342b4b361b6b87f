"""What a curriculum did, kept in the run directory: the buffer at every checkpoint.

``OUT/curriculum/buffer-UPDATE.npz`` holds the buffer's latents, scores, episode counts and
ages at that update (filled slots only), so a run can be read back as a film of what training
was steered toward (``reports.curriculum``). The last snapshot's ``FAVOURITES`` highest scores are
the worlds it favoured most: drawn and listed by the report, confirmed on fresh episodes by
``analysis.favoured``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import numpy as np

from worldagent.curricula.buffer import Buffer
from worldagent.files import write_atomically

FOLDER = "curriculum"
FAVOURITES = 4  # the latents of highest score a run reports (drawn, listed, confirmed) per environment


def find_buffer(state: Any) -> Buffer | None:
    """The curriculum buffer inside a trainer state, or None (``dr``)."""
    found = [leaf for leaf in jax.tree_util.tree_leaves(state, is_leaf=lambda x: isinstance(x, Buffer)) if isinstance(leaf, Buffer)]
    return found[0] if found else None


def save_snapshot(out_dir: Path, state: Any, update: int) -> Path | None:
    """Write the buffer of ``state`` at ``update`` (nothing for a curriculum without one)."""
    buffer = find_buffer(state)
    if buffer is None:
        return None
    buffer = jax.device_get(buffer)
    used = np.asarray(buffer.count) > 0
    path = Path(out_dir) / FOLDER / f"buffer-{update:07d}.npz"
    arrays = {
        "update": np.int64(update),
        "z": np.asarray(buffer.z)[used],
        "score": np.asarray(buffer.score)[used],
        "count": np.asarray(buffer.count)[used],
        "age": (int(buffer.clock) - np.asarray(buffer.last))[used],
    }

    def save(tmp: Path) -> None:
        with open(tmp, "wb") as handle:  # a handle: np.savez would append ".npz" to the temp name
            np.savez(handle, **arrays)

    return write_atomically(path, save)


def load_snapshots(out_dir: Path) -> list[dict[str, np.ndarray]]:
    """Every snapshot of a run, in update order ([] when it kept none)."""
    paths = sorted((Path(out_dir) / FOLDER).glob("buffer-*.npz"))
    return [dict(np.load(path)) for path in paths]


def favourite_order(snapshot: dict, count: int = FAVOURITES) -> np.ndarray:
    """int[k]: the buffer slots of the ``count`` highest scores in a snapshot (best first, earliest slot on ties)."""
    return np.argsort(-np.asarray(snapshot["score"]), kind="stable")[:count]
