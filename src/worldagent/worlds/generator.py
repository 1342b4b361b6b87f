"""The World Agent's generator G(z) = repair(decoder(z)) (paper §4.2, Equation 3, Figure 3).

``Generator`` is a pytree: pass it *into* jitted code as an argument (it holds the decoder's
weights and the repair step's arrays, e.g. the dataset's worlds for a nearest-world repair,
which must not be baked into a compiled program as constants). Calling it is pure and
jittable::

    worlds = generator(z)          # z: f32[B, 10] -> a batch of B worlds

The repair step is the environment's (``registry.get(env).repair(dataset, config)``); this
module never asks which environment it serves.

On a generator directory (``save``/``load``): ``vae.msgpack`` + ``vae.json`` (the VAE) and
``generator.json`` (env, the dataset file and its fingerprint, the repair's name and config).
Which repair G uses is chosen by name (``EnvSpec.repairs``: e.g. the paper's ``nearest``, which
returns dataset worlds only, or an ``open`` one that builds new valid worlds) and recorded with
every setting, defaults included, so a generator loads as it was trained.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from worldagent.envs import registry
from worldagent.envs.core import check_finite
from worldagent.envs.registry import DEFAULT_REPAIR
from worldagent.errors import WorldagentError
from worldagent.files import write_text
from worldagent.worlds.dataset import WorldDataset
from worldagent.worlds.vae import VAE, TrainedVAE, logits_layer

GENERATOR_FILE = "generator.json"
FIT_LATENTS = 256  # decodes of the prior a repair fits itself on (``fit_repair``): a mean count to about 3 %
FIT_SEED = 7  # their key, apart from the quality report's and the benchmarks' key 0


@struct.dataclass
class Generator:
    """G(z) for one environment.

    Attributes:
        params: the VAE's parameters (the decoder's are used by G; the encoder's by ``encode``).
        repair: the environment's repair step, a pytree with ``__call__(logits f32[B, D]) ->
            worlds[B]`` and a JSON-able ``config`` (``EnvSpec.repair``).
        model: the ``VAE`` module (static).
        env: the environment's registered name (static).
        cell_shape: shape of one world's cells (static).
        repair_name: the repair's name in ``EnvSpec.repairs`` (static).
        folded: the repair moved behind the decoder's last layer where it allows it (``repair.fold``,
            e.g. a nearest-world repair, which is linear in the logits): the same worlds, fewer
            products. None: G decodes logits, then repairs them.
    """

    params: Any
    repair: Any
    model: VAE = struct.field(pytree_node=False)
    env: str = struct.field(pytree_node=False)
    cell_shape: tuple = struct.field(pytree_node=False)
    repair_name: str = struct.field(pytree_node=False, default=DEFAULT_REPAIR)
    folded: Any = None

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

    def _decoder(self, z: jax.Array, method=VAE.decode) -> jax.Array:
        """``method`` of the decoder (default ``VAE.decode``) on latents z f[B, latent_dim], checked."""
        self.check_latents(z)
        return self.model.apply({"params": self.params}, jnp.asarray(z, jnp.float32), method=method)

    def logits(self, z: jax.Array) -> jax.Array:
        """f32[B, D] decoded Bernoulli logits of the cells for latents z f[B, latent_dim]."""
        return self._decoder(z)

    def encode(self, cells) -> jax.Array:
        """f32[B, latent_dim]: the encoder's mean latent of each world's cells f[B, D]."""
        return self.model.apply({"params": self.params}, jnp.asarray(cells, jnp.float32), method=VAE.encode)[0]

    def __call__(self, z: jax.Array) -> Any:
        """A batch of B valid worlds for latents z f[B, latent_dim] (paper Equation 3)."""
        if self.folded is None:
            return self.repair(self.logits(z))
        hidden = self._decoder(z, VAE.hidden)
        return self.folded(jnp.concatenate([hidden, jnp.ones((len(hidden), 1), hidden.dtype)], axis=1))


def _repair_config(meta: Mapping[str, Any]) -> dict:
    """The repair config recorded in ``generator.json`` (old files recorded harvest's ``apples``)."""
    if "repair" in meta:
        return dict(meta["repair"] or {})
    return {"apples": meta["apples"]} if meta.get("apples") else {}


def _repair_name(meta: Mapping[str, Any]) -> str | None:
    """The repair's name recorded in ``generator.json`` (None in files from before names: the default)."""
    return meta.get("repair_name")


def make_repair(dataset: WorldDataset, repair_config: Mapping[str, Any] | None = None, name: str | None = None) -> Any:
    """The environment's repair called ``name`` (None: its default) for ``dataset``, given only the
    settings named (None or ``{}``: its defaults); its ``config`` holds them all. ``generator train``
    calls it before the VAE trains, so a bad name or bad settings cost no training.

    A repair refuses unknown names and bad values with a ``WorldagentError``; one that raises
    ``TypeError``, ``ValueError`` or ``KeyError`` instead, when made or when traced on one
    abstract batch of logits (a value of the wrong type fails there), is reported in one line too.
    """
    spec = registry.get(dataset.env)
    factory = spec.repair_factory(name)
    settings = dict(repair_config or {})
    try:
        repair = factory(dataset, settings)
        jax.eval_shape(repair, jax.ShapeDtypeStruct((1, spec.cell_count), jnp.float32))  # shapes only: nothing is computed
        return repair
    except WorldagentError:
        raise
    except (TypeError, ValueError, KeyError) as error:
        given = ", ".join(f"{name}={value!r}" for name, value in settings.items()) or "none"
        raise WorldagentError(f"{spec.name}'s repair refuses its settings ({given}): {error}; fix or drop --repair.") from None


def build_generator(
    vae: TrainedVAE, dataset: WorldDataset, repair_config: Mapping[str, Any] | None = None, repair: Any = None, repair_name: str | None = None
) -> Generator:
    """G(z) from a trained VAE and the dataset it was trained on.

    Args:
        vae: the trained VAE.
        dataset: its training dataset (the repair may map to its worlds or measure them).
        repair_config: settings of the environment's repair (e.g. ``{"apples": K}`` for harvest);
            None or ``{}``: the repair's defaults.
        repair: a repair already made for ``dataset`` (``make_repair``), instead of ``repair_config``.
        repair_name: the name of the repair in ``EnvSpec.repairs`` (None: the env's default).
    """
    if vae.env != dataset.env or vae.fingerprint != dataset.fingerprint:
        raise WorldagentError(
            f"the VAE was trained on {vae.env} dataset {vae.fingerprint}, not on this {dataset.env} dataset {dataset.fingerprint}; "
            "pass the dataset it was trained on."
        )
    repair = repair if repair is not None else make_repair(dataset, repair_config, repair_name)
    folded = repair.fold(*logits_layer(vae.params)) if hasattr(repair, "fold") else None
    spec = registry.get(dataset.env)
    name = spec.default_repair if repair_name in (None, DEFAULT_REPAIR) else repair_name
    return Generator(vae.params, repair, vae.model, dataset.env, tuple(vae.cell_shape), name, folded)


def fit_repair(generator: Generator, dataset: WorldDataset) -> Generator:
    """G with its repair fitted to its decoder, when G is first made: a repair with ``fitted(logits f32[B, D],
    worlds)`` (e.g. harvest's, whose logit shifts make decodes of the prior hold the rooms and apples of the
    training ``dataset``'s worlds) sees ``FIT_LATENTS`` decodes of z ~ N(0, I) and records what it fitted in
    its config, so a saved G decodes as it did without fitting again. G itself when its repair fits nothing."""
    if not hasattr(generator.repair, "fitted"):
        return generator
    z = jax.random.normal(jax.random.key(FIT_SEED), (FIT_LATENTS, generator.latent_dim))
    repair = generator.repair.fitted(generator.logits(z), dataset.worlds)
    if repair is generator.repair:
        return generator
    folded = repair.fold(*logits_layer(generator.params)) if hasattr(repair, "fold") else None
    return generator.replace(repair=repair, folded=folded)


def save_generator(directory: Path | str, vae: TrainedVAE, dataset_path: Path | str, generator: Generator) -> Path:
    """Write the VAE and ``generator.json`` (env, dataset file, fingerprint, repair config) to ``directory``."""
    directory = Path(directory)
    vae.save(directory)
    meta = {
        "env": generator.env,
        "dataset": str(Path(dataset_path).resolve()),
        "fingerprint": vae.fingerprint,
        "repair_name": generator.repair_name,
        "repair": dict(generator.repair.config),
    }
    write_text(directory / GENERATOR_FILE, json.dumps(meta, indent=1))
    return directory


def load_generator(
    directory: Path | str, dataset_path: Path | str | None = None, env: str | None = None
) -> tuple[Generator, TrainedVAE, WorldDataset]:
    """(G, its VAE, its dataset) from a generator directory; ``dataset_path`` overrides the recorded one; ``env``, when the
    caller knows it, names the environment in the command a refusal gives."""
    directory = Path(directory)
    try:
        meta = json.loads((directory / GENERATOR_FILE).read_text())
    except (OSError, ValueError):
        raise WorldagentError(
            f"{directory} holds no generator; train one with `worldagent generator train {env or 'ENV'} --out {directory}`."
        ) from None
    vae = TrainedVAE.load(directory, env or meta.get("env"))
    dataset = WorldDataset.load(dataset_path or meta["dataset"], env=meta["env"])
    return build_generator(vae, dataset, _repair_config(meta), repair_name=_repair_name(meta)), vae, dataset
