"""World distributions: where a training run draws each episode's world from (paper §4.3).

One small interface. A distribution is a ``flax.struct`` pytree (pass it *into* jitted code as
an argument, so its arrays are not baked into the compiled program) with one pure method::

    world = distribution.sample(key)                       # ONE unbatched world
    worlds = jax.vmap(distribution.sample)(keys)           # a batch, one world per key

Two kinds cover the issue's three cases:

- ``WorldPool(worlds, probs)``: a batched world pytree (leading axis N) drawn by weight. The
  procedural generator is a pool of e.g. 10,000 generated worlds drawn uniformly (the paper
  trains on "a distribution of procedurally generated environments", §6.1); a fixed list of
  worlds with weights is the influenced training distribution (§6.2).
- ``LatentWorlds(generator)``: ``G(z)`` with ``z ~ N(0, I)`` (paper Equation 3).

``world_distribution(env, spec_text, ...)`` builds one on the host from a string: ``"generator"``
(a procedural pool), ``"vae"`` (needs a generator directory), or a dataset ``.npz`` path.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from worldagent.envs import registry
from worldagent.errors import WorldagentError

DEFAULT_POOL_SIZE = 10_000  # the paper's dataset size (§5.2.1)


def _take(worlds: Any, index) -> Any:
    """World ``index`` of a batched world pytree (works on tracers)."""
    return jax.tree_util.tree_map(lambda leaf: leaf[index], worlds)


def check_weights(weights, n: int) -> np.ndarray:
    """Host-side: ``weights`` must be N finite, non-negative numbers, not all zero; returns f64[N] that sum to 1."""
    array = np.asarray(weights, dtype=np.float64)
    if array.shape != (n,):
        raise WorldagentError(f"weights have shape {array.shape}; expected ({n},), one per world.")
    if not np.all(np.isfinite(array)):
        raise WorldagentError("weights contain NaN or infinite values; pass finite, non-negative weights.")
    if np.any(array < 0):
        raise WorldagentError(f"weights contain negative values (min {array.min():.3g}); pass non-negative weights.")
    total = array.sum()
    if total <= 0:
        raise WorldagentError("weights are all zero; give at least one world a positive weight.")
    return array / total


@struct.dataclass
class WorldPool:
    """A fixed list of worlds drawn with probabilities (uniform by default).

    Build with ``WorldPool.create(worlds, weights)`` (which checks the weights); the fields are:

    Attributes:
        worlds: the batched world pytree, every leaf with leading axis N.
        probs: f32[N] sampling probabilities (non-negative, sum 1).
        cdf: f32[N] their cumulative sum (last entry exactly 1): ``sample`` inverts it with a
            binary search, O(log N) per draw (a categorical over logits would cost O(N)).
    """

    worlds: Any
    probs: jax.Array
    cdf: jax.Array

    @classmethod
    def create(cls, worlds: Any, weights=None) -> WorldPool:
        """A pool of the N worlds in ``worlds`` (leading axis N), drawn by ``weights`` f[N] (default uniform)."""
        leaves = jax.tree_util.tree_leaves(worlds)
        if not leaves or np.ndim(leaves[0]) == 0:
            raise WorldagentError("worlds must be a batched world pytree with a leading axis (e.g. a dataset's .worlds).")
        n = int(np.shape(leaves[0])[0])
        if n < 1 or any(np.shape(leaf)[:1] != (n,) for leaf in leaves):
            raise WorldagentError(f"worlds must all share one leading axis of size >= 1; got leaf shapes {[np.shape(x) for x in leaves]}.")
        probs = np.full(n, 1.0 / n) if weights is None else check_weights(weights, n)
        cdf = np.cumsum(probs)
        cdf[np.flatnonzero(probs)[-1] :] = 1.0  # no rounding gap at the top; trailing zero weights stay unreachable
        worlds = jax.tree_util.tree_map(jnp.asarray, worlds)
        return cls(worlds, jnp.asarray(probs, jnp.float32), jnp.asarray(cdf, jnp.float32))

    @property
    def size(self) -> int:
        """N, the number of worlds in the pool."""
        return int(self.probs.shape[-1])

    def sample_index(self, key: jax.Array) -> jax.Array:
        """i32 index of a world drawn with probability ``probs``."""
        u = jax.random.uniform(key, (), jnp.float32)
        index = jnp.searchsorted(self.cdf, u, side="right")  # first i with cdf[i] > u: zero weights never drawn
        return jnp.minimum(index, self.cdf.shape[-1] - 1).astype(jnp.int32)

    def sample(self, key: jax.Array) -> Any:
        """One unbatched world drawn with probability ``probs`` (pure, jittable)."""
        return _take(self.worlds, self.sample_index(key))

    def sample_batch(self, key: jax.Array, n: int) -> Any:
        """A batch of ``n`` independent draws (leading axis n)."""
        return jax.vmap(self.sample)(jax.random.split(key, n))


@struct.dataclass
class LatentWorlds:
    """Worlds ``G(z)`` with ``z ~ N(0, I)`` (paper Equation 3): the VAE generator as a distribution.

    Attributes:
        generator: a ``worldagent.worlds.generator.Generator`` (a pytree).
    """

    generator: Any

    @property
    def latent_dim(self) -> int:
        return self.generator.latent_dim

    def sample_latent(self, key: jax.Array) -> jax.Array:
        """f32[latent_dim] standard normal latent."""
        return jax.random.normal(key, (self.latent_dim,), jnp.float32)

    def sample(self, key: jax.Array) -> Any:
        """One unbatched world ``G(z)`` (pure, jittable)."""
        return _take(self.generator(self.sample_latent(key)[None]), 0)

    def sample_batch(self, key: jax.Array, n: int) -> Any:
        """A batch of ``n`` worlds from ``n`` independent latents, decoded at once."""
        z = jax.random.normal(key, (n, self.latent_dim), jnp.float32)
        return self.generator(z)


WorldDistribution = WorldPool | LatentWorlds


def procedural_pool(env: Any, size: int = DEFAULT_POOL_SIZE, seed: int = 0, progress: bool = False) -> WorldPool:
    """The procedural generator of ``env`` (a name or ``EnvSpec``) as a uniform pool of ``size`` worlds, seeds ``seed, seed+1, ...``."""
    from worldagent.worlds.dataset import make_dataset

    return WorldPool.create(make_dataset(registry.get(env), size, seed, progress=progress).worlds)


def world_distribution(
    env: Any,
    spec_text: str,
    *,
    size: int = DEFAULT_POOL_SIZE,
    seed: int = 0,
    generator_dir: str | Path | None = None,
    weights=None,
    progress: bool = False,
) -> WorldPool | LatentWorlds:
    """Build a world distribution on the host from a spec string.

    Args:
        env: the environment, a registered name or an ``EnvSpec``.
        spec_text: ``"generator"``: the procedural generator, a uniform pool of ``size`` worlds from
            seeds ``seed, seed+1, ...``; ``"vae"``: ``G(z)``, ``z ~ N(0, I)``, from the generator
            directory ``generator_dir`` (a directory holding ``generator.json`` may also be given
            as the spec itself); or the path of a dataset ``.npz`` (``worldagent dataset``), its
            worlds drawn by ``weights`` (default uniform).
        size, seed: the procedural pool's size and first seed.
        generator_dir: the generator directory for ``"vae"``.
        weights: f[N] per-world weights for a dataset file (e.g. the influenced distribution).
        progress: show a progress bar while generating.

    Returns:
        A ``WorldPool`` or ``LatentWorlds``.
    """
    name = registry.get(env).name
    if not isinstance(spec_text, (str, Path)):
        raise WorldagentError(f"world distribution {spec_text!r} is not a string; use 'generator', 'vae' or a dataset .npz path.")
    text = str(spec_text)
    if text == "generator":
        if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 1:
            raise WorldagentError(f"pool size={size!r}; ask for at least 1 world.")
        if weights is not None:
            raise WorldagentError("weights apply to a dataset file; save the worlds as a dataset and pass its path.")
        return procedural_pool(name, int(size), seed, progress)
    if text == "vae" or (Path(text).is_dir() and (Path(text) / "generator.json").is_file()):
        directory = generator_dir if text == "vae" else text
        if directory is None:
            raise WorldagentError("'vae' needs a generator directory; pass generator_dir (made by `worldagent generator train`).")
        from worldagent.worlds.generator import load_generator

        generator, _, _ = load_generator(directory, env=name)
        if generator.env != name:
            raise WorldagentError(f"generator {directory} makes {generator.env} worlds, not {name} worlds; pass a {name} generator.")
        return LatentWorlds(generator)
    path = Path(text)
    if path.suffix == ".npz" or path.exists():
        from worldagent.worlds.dataset import WorldDataset

        return WorldPool.create(WorldDataset.load(path, env=name).worlds, weights)
    raise WorldagentError(f"unknown world distribution {text!r}; use 'generator', 'vae' or the path of a dataset .npz file.")
