"""The unrepaired decode, for the generator's "valid before repair" figure.

G(z) repairs decoded cells with worldagent's ``NearestWorld`` (``spec.py``): the dataset world
the decoder finds most probable, so every repaired world is valid and its goal reachable with no
repair code here.
"""

from __future__ import annotations

import numpy as np

from .world import SIZE, LavaGrid

CELLS = SIZE * SIZE


def raw_decode(logits) -> LavaGrid:
    """Thresholded cells without repair (may hold no goal, several, or no safe path)."""
    cells = np.asarray(logits) > 0
    return LavaGrid(lava=cells[:, :CELLS].reshape(-1, SIZE, SIZE), goal=cells[:, CELLS:].reshape(-1, SIZE, SIZE))
