"""Pictures of a generator: traversals and reconstructions, drawn from the spec, for any cell shape."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from worldagent.worlds.pictures import LABEL, probability_tile, reconstruction_sheet, traversal_sheet, world_tile


@pytest.mark.parametrize("shape", [(64, 64), (2, 25, 25), (3, 4, 5), (10,)])
def test_probability_tiles_draw_any_cell_shape(shape):
    logits = np.linspace(-20, 20, int(np.prod(shape)))
    tile = probability_tile(logits, shape, 40)
    assert tile.size == (40, 40) and tile.mode == "RGB"
    grey = np.asarray(tile)[..., 0]
    assert grey.min() < 10 and grey.max() > 245  # sure cells dark, unlikely ones white


@pytest.mark.parametrize("which", ["racing", "harvest"])
def test_sheets_are_drawn_for_each_environment(tmp_path, which, request):
    generator = request.getfixturevalue(f"{which}_generator")
    data = request.getfixturevalue(f"{which}_data")
    assert world_tile(which, data.world(0), 32).size == (32, 32)
    traversal = Image.open(traversal_sheet(generator, tmp_path / "t.png", steps=3, size=32))
    assert traversal.size == (3 * 32, generator.latent_dim * (32 + LABEL))
    rebuilt = Image.open(reconstruction_sheet(generator, data, [0, 3], tmp_path / "r.png", size=32))
    assert rebuilt.size == (3 * 32, 2 * (32 + LABEL))
