"""The World Agent's generator G(z) = repair(decoder(z)) (paper §4.2, Equation 3, Figure 3).

``Generator`` is a pytree: pass it *into* jitted code as an argument (it holds the decoder's
weights and, for racing, the dataset's rasters and tracks, which must not be baked into a
compiled program as constants). Calling it is pure and jittable::

    worlds = generator(z)          # z: f32[B, 10] -> a batch of B worlds

On a generator directory (``save``/``load``): ``vae.msgpack`` + ``vae.json`` (the VAE) and
``generator.json`` (env, the dataset file and its fingerprint, the harvest apple count).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from worldagent.envs.core import check_finite
from worldagent.errors import WorldagentError
from worldagent.files import write_text
from worldagent.worlds.dataset import WorldDataset
from worldagent.worlds.repair import nearest_track, repair_harvest
from worldagent.worlds.vae import VAE, TrainedVAE

GENERATOR_FILE = "generator.json"


@struct.dataclass
class Generator:
    """G(z) for one environment.

    Attributes:
        params: the VAE's parameters (the decoder's are used by G; the encoder's by ``encode``).
        rasters: racing: f32[N, D] the dataset's rasters; harvest: unused (f32[0, 0]).
        worlds: racing: the dataset's tracks (batched ``Track``); harvest: None.
        model: the ``VAE`` module (static).
        env: "racing" or "harvest" (static).
        cell_shape: shape of one world's cells (static).
        apples: harvest: K, the apple count of every generated map; racing: 0 (static).
    """

    params: Any
    rasters: jax.Array
    worlds: Any
    model: VAE = struct.field(pytree_node=False)
    env: str = struct.field(pytree_node=False)
    cell_shape: tuple = struct.field(pytree_node=False)
    apples: int = struct.field(pytree_node=False, default=0)

    @property
    def latent_dim(self) -> int:
        return self.model.latent_dim

    def check_latents(self, z) -> None:
        """Host-side: ``z`` must be f[B, latent_dim] and, when concrete, finite."""
        shape = np.shape(z)
        if len(shape) != 2 or shape[1] != self.latent_dim:
            raise WorldagentError(f"latents have shape {shape}; expected (B, {self.latent_dim}).")
        if not isinstance(z, jax.core.Tracer):
            check_finite("latents", z)

    def logits(self, z: jax.Array) -> jax.Array:
        """f32[B, D] decoded Bernoulli logits of the cells."""
        self.check_latents(z)
        return self.model.apply({"params": self.params}, jnp.asarray(z, jnp.float32), method=VAE.decode)

    def encode(self, cells) -> jax.Array:
        """f32[B, latent_dim]: the encoder's mean latent of each world's cells."""
        return self.model.apply({"params": self.params}, jnp.asarray(cells, jnp.float32), method=VAE.encode)[0]

    def track_indices(self, z: jax.Array) -> jax.Array:
        """Racing: i32[B] the dataset index of the track G(z) returns."""
        return nearest_track(self.logits(z), self.rasters)

    def __call__(self, z: jax.Array) -> Any:
        """A batch of B valid worlds for latents z f[B, latent_dim] (paper Equation 3)."""
        if self.env == "racing":
            index = self.track_indices(z)
            return jax.tree_util.tree_map(lambda leaf: leaf[index], self.worlds)
        logits = self.logits(z).reshape(-1, *self.cell_shape)
        return repair_harvest(logits, self.apples)


def median_apples(dataset: WorldDataset) -> int:
    """The median apple count of a harvest dataset (the default K of harvest repair)."""
    return int(np.median(np.asarray(dataset.worlds.apples).reshape(len(dataset), -1).sum(axis=1)))


def build_generator(vae: TrainedVAE, dataset: WorldDataset, apples: int | None = None) -> Generator:
    """G(z) from a trained VAE and the dataset it was trained on.

    Args:
        vae: the trained VAE.
        dataset: its training dataset (racing repair maps to these tracks).
        apples: harvest only: K, the apples per map (default: the dataset's median).
    """
    if vae.env != dataset.env or vae.fingerprint != dataset.fingerprint:
        raise WorldagentError(
            f"the VAE was trained on {vae.env} dataset {vae.fingerprint}, not on this {dataset.env} dataset {dataset.fingerprint}; "
            "pass the dataset it was trained on."
        )
    if dataset.env == "racing":
        rasters = jnp.asarray(dataset.cells, jnp.float32)
        worlds = jax.tree_util.tree_map(jnp.asarray, dataset.worlds)
        return Generator(vae.params, rasters, worlds, vae.model, "racing", tuple(vae.cell_shape), 0)
    count = median_apples(dataset) if apples is None else int(apples)
    free = int(np.prod(vae.cell_shape[1:])) - 4
    if not 1 <= count <= free:
        raise WorldagentError(f"apples={count}; pick between 1 and {free} (the non-corner cells of the map).")
    return Generator(vae.params, jnp.zeros((0, 0)), None, vae.model, "harvest", tuple(vae.cell_shape), count)


def save_generator(directory: Path | str, vae: TrainedVAE, dataset_path: Path | str, generator: Generator) -> Path:
    """Write the VAE and ``generator.json`` (dataset file, fingerprint, apple count) to ``directory``."""
    directory = Path(directory)
    vae.save(directory)
    meta = {"env": generator.env, "dataset": str(Path(dataset_path).resolve()), "fingerprint": vae.fingerprint, "apples": generator.apples}
    write_text(directory / GENERATOR_FILE, json.dumps(meta, indent=1))
    return directory


def load_generator(directory: Path | str, dataset_path: Path | str | None = None) -> tuple[Generator, TrainedVAE, WorldDataset]:
    """(G, its VAE, its dataset) from a generator directory; ``dataset_path`` overrides the recorded one."""
    directory = Path(directory)
    try:
        meta = json.loads((directory / GENERATOR_FILE).read_text())
    except (OSError, ValueError):
        raise WorldagentError(
            f"{directory} holds no generator; train one with `worldagent generator train racing|harvest --out {directory}`."
        ) from None
    vae = TrainedVAE.load(directory)
    dataset = WorldDataset.load(dataset_path or meta["dataset"], env=meta["env"])
    return build_generator(vae, dataset, meta["apples"] or None), vae, dataset
