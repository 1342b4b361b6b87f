"""Pictures of a generator: latent traversals and reconstructions (paper Figure 3).

``traversal_sheet``: one row per latent dimension, G(z) with that coordinate swept from -span
to +span and the others at 0. ``reconstruction_sheet``: for some dataset worlds, the original,
the decoder's cell probabilities (grey), and the repaired world G(encode(x)).
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from PIL import Image, ImageDraw, ImageFont

from worldagent.envs import registry
from worldagent.envs.registry import EnvSpec
from worldagent.files import save_png
from worldagent.worlds.dataset import WorldDataset
from worldagent.worlds.generator import Generator

LABEL = 14  # pixels above each tile for its caption


def world_tile(env: str | EnvSpec, world, size: int) -> Image.Image:
    """One unbatched world drawn ``size×size`` as its environment draws it (``spec.pictures.world``)."""
    return registry.get(env).pictures.world(world, size).convert("RGB")


def _channels(probability: np.ndarray) -> np.ndarray:
    """f[H, W']: a cell grid of any rank as one image, channels (leading axes) side by side, 1 px apart."""
    if probability.ndim < 2:
        return probability.reshape(1, -1)
    grids = probability.reshape(-1, *probability.shape[-2:])
    gap = np.ones((grids.shape[1], 1))
    return np.concatenate([part for grid in grids for part in (gap, grid)][1:], axis=1)


def probability_tile(logits: np.ndarray, cell_shape: tuple, size: int) -> Image.Image:
    """Decoded cell probabilities (logits f[D]) as grey levels, darker for likelier cells.

    Args:
        logits: f[D] one world's decoded logits.
        cell_shape: one world's cell shape (``EnvSpec.cell_shape``), e.g. (64, 64), or (2, 25, 25)
            whose leading channels (harvest: walls, apples) are drawn side by side.
        size: the tile's side in pixels.
    """
    probability = 1.0 / (1.0 + np.exp(-np.asarray(logits, np.float64).reshape(cell_shape)))
    grey = Image.fromarray((255 * (1.0 - _channels(probability))).astype(np.uint8), mode="L").convert("RGB")
    return grey.resize((size, size), Image.NEAREST)


def _sheet(tiles: list[list[Image.Image]], captions: list[list[str]], size: int) -> Image.Image:
    rows, columns = len(tiles), max(len(row) for row in tiles)
    sheet = Image.new("RGB", (columns * size, rows * (size + LABEL)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    font = ImageFont.load_default()
    for r, (row, texts) in enumerate(zip(tiles, captions)):
        for c, (tile, text) in enumerate(zip(row, texts)):
            x, y = c * size, r * (size + LABEL)
            sheet.paste(tile, (x, y + LABEL))
            draw.text((x + 3, y + 1), text, fill=(0, 0, 0), font=font)
    return sheet


def _index(worlds, i):
    return jax.tree_util.tree_map(lambda leaf: np.asarray(leaf[i]), worlds)


def traversal_sheet(generator: Generator, out: Path | str, steps: int = 7, span: float = 2.5, size: int = 96) -> Path:
    """Draw G(z) along each latent axis (rows) for ``steps`` values in [-span, span] (columns)."""
    values = np.linspace(-span, span, steps)
    dims = generator.latent_dim
    z = np.zeros((dims, steps, dims), np.float32)
    z[np.arange(dims), :, np.arange(dims)] = values
    worlds = jax.jit(lambda g, z: g(z))(generator, jnp.asarray(z.reshape(-1, dims)))
    tiles = [[world_tile(generator.env, _index(worlds, d * steps + s), size) for s in range(steps)] for d in range(dims)]
    captions = [[f"z{d} = {v:+.1f}" for v in values] for d in range(dims)]
    return save_png(_sheet(tiles, captions, size), out)


def reconstruction_sheet(generator: Generator, dataset: WorldDataset, indices, out: Path | str, size: int = 96) -> Path:
    """Draw, for each dataset index: the original, the decoded probabilities, and G(encode(x))."""
    indices = np.asarray(indices)
    cells = jnp.asarray(dataset.cells[indices], jnp.float32)
    latents = jax.jit(lambda g, c: g.encode(c))(generator, cells)
    logits = np.asarray(jax.jit(lambda g, z: g.logits(z))(generator, latents))
    rebuilt = jax.jit(lambda g, z: g(z))(generator, latents)
    tiles, captions = [], []
    for row, index in enumerate(indices):
        tiles.append(
            [
                world_tile(dataset.env, dataset.world(int(index)), size),
                probability_tile(logits[row], dataset.cell_shape, size),
                world_tile(dataset.env, _index(rebuilt, row), size),
            ]
        )
        captions.append([f"world {int(index)}", "decoded", "G(encode(x))"])
    return save_png(_sheet(tiles, captions, size), out)
