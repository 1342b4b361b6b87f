"""A surrogate of the event from what a world looks like, for importance sampling (``failure_rate``).

Multifidelity importance sampling (Peherstorfer, Cui, Marzouk & Willcox, 2016): a cheap model
of the expensive one shapes the proposal; the expensive one (episodes) only scores it, so the
estimate stays unbiased however poor the cheap model is (a poor one costs variance only).

Here the cheap model reads a world's *descriptors* (``EnvSpec.metrics.descriptors``: a track's
length and curvature, a map's wall share) and its latent, which cost a decode and no episode.
It is a ridge regression of the event's margin on ``features`` = [1, z, z², standardised
descriptors], fitted once on a pilot of worlds from the prior; with the spread σ of its
leave-one-out residuals it gives each world a chance Φ(margin̂ / σ) of being in the event.

Why descriptors: a generator that repairs to its dataset's worlds makes an event a union of
small latent cells, one per track, which a proposal in latent space must find one by one; in
descriptor space they are one region (racing's slow laps are its long tracks: corr(steps,
length) 0.81 on the benchmark's 200,000 worlds). Why z²: two regions on either side of the
prior (|z0| > c). Why linear, fitted once on the prior: with cross terms it overfitted the pilot
and its extrapolation put no mass on the event; refitted on the proposal's own worlds it leant
to the regions it had already drawn and its estimates fell to 0.4-0.7 P with tight intervals
(docs/failure-rate.md).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy.special import log_ndtr, logsumexp

from worldagent.errors import WorldagentError

RIDGE = 1.0  # on standardised features: shrinks what a pilot of a few hundred worlds cannot pin down


def features(z: np.ndarray, described: np.ndarray | None = None, reference: int | None = None) -> np.ndarray:
    """f64[n, f]: [1, z, z², descriptors] of latents z f64[n, dim] and their worlds' descriptors f64[n, k] (or None).

    The descriptors are standardised by the mean and spread of the first ``reference`` rows (None:
    all n), and those constant there dropped: every world is scaled alike, and a pool described
    in two parts (a timed sample first) is scaled as its sample was.
    """
    z = np.asarray(z, np.float64)
    columns = [np.ones((len(z), 1)), z, z**2]
    if described is not None and np.size(described):
        described = np.asarray(described, np.float64).reshape(len(z), -1)
        head = described[: len(z) if reference is None else reference]
        spread = head.std(axis=0)
        varying = spread > 0
        columns.append((described[:, varying] - head[:, varying].mean(axis=0)) / spread[varying])
    return np.concatenate(columns, axis=1)


def log_chances(pool: np.ndarray, pilot: np.ndarray, margins: np.ndarray) -> np.ndarray:
    """f64[M]: log Φ(margin̂ / σ), each pool world's modelled chance of the event.

    σ is the spread of the pilot's leave-one-out residuals: a pilot with about as many worlds as
    features fits itself exactly, and its in-sample residuals would make the chances step
    functions (a 25-world pilot on 25 features put the weights of harvest's quick run on 3 worlds).

    Args:
        pool: f64[M, f] features of the worlds to score.
        pilot: f64[m, f] features of the evaluated worlds (from the prior).
        margins: f64[m] their margins (> 0 inside the event; -inf rows are left out).

    Raises:
        WorldagentError: when fewer than 2 pilot worlds have a finite margin.
    """
    finite = np.isfinite(margins)
    if finite.sum() < 2:
        raise WorldagentError("the event's metrics are NaN on the pilot's worlds; check the policy and the metrics.")
    x, y = pilot[finite], np.asarray(margins, np.float64)[finite]
    inverse = np.linalg.inv(x.T @ x + RIDGE * np.eye(x.shape[1]))
    coefficients = inverse @ (x.T @ y)
    leverage = np.einsum("ij,jk,ik->i", x, inverse, x)  # the hat matrix's diagonal
    held_out = (y - x @ coefficients) / np.maximum(1 - leverage, 1e-9)  # leave-one-out residuals, in closed form
    spread = max(float(np.sqrt(np.mean(held_out**2))), 1e-9 * (float(np.std(y)) + 1e-300))
    return log_ndtr(pool @ coefficients / spread)


def pool_shares(log_chance: np.ndarray, prior_weight: float) -> np.ndarray:
    """f64[M] sampling probabilities over the pool: α/M + (1 − α) · chance / Σ chance (each world's weight ≤ 1/α)."""
    modelled = np.exp(log_chance - logsumexp(log_chance))
    return prior_weight / len(log_chance) + (1 - prior_weight) * modelled


def distinct_describer(
    spec: Any, generator: Any, names: Sequence[str] | None = None, chunk: int = 10_000, progress: bool = False
) -> Callable[[np.ndarray], np.ndarray]:
    """``describe(z f64[n, dim]) -> f64[n, k]``: the descriptors of the worlds G(z), each distinct world described once.

    G decodes ``chunk`` latents at a time (the last padded, so it compiles once). A repair to a
    dataset's worlds maps many latents to one world, so the (Python) descriptors run on the
    distinct ones only: on racing ~1,800 of every 10,000.

    Args:
        names: descriptors of ``spec.metrics.descriptors`` (None: all of them).
        progress: a progress bar over the latents.
    """
    import jax
    import jax.numpy as jnp

    from worldagent.progress import progress_bar
    from worldagent.search.objectives import generate

    names = tuple(spec.metrics.descriptors) if names is None else tuple(names)
    unknown = [name for name in names if name not in spec.metrics.descriptors]
    if unknown:
        raise WorldagentError(f"unknown {spec.name} descriptor(s) {unknown}; use {', '.join(spec.metrics.descriptors) or 'none'}.")
    functions = [spec.metrics.descriptors[name] for name in names]

    def describe(z: np.ndarray) -> np.ndarray:
        z = np.asarray(z, np.float32)
        rows = np.zeros((len(z), len(functions)))
        size = min(chunk, len(z))
        with progress_bar("describing the pool", total=len(z), enabled=progress) as advance:
            for start in range(0, len(z), size):
                rows[start : start + size] = _describe_chunk(z[start : start + size], size)
                advance(min(size, len(z) - start))
        return rows

    def _describe_chunk(part: np.ndarray, size: int) -> np.ndarray:
        """f64[len(part), k] for at most ``size`` latents: G decodes them padded to ``size``."""
        padded = np.concatenate([part, np.zeros((size - len(part), part.shape[1]), np.float32)])
        worlds = jax.tree_util.tree_map(lambda leaf: np.asarray(leaf)[: len(part)], generate(generator, jnp.asarray(padded)))
        flat = np.concatenate([np.ascontiguousarray(leaf).reshape(len(part), -1).view(np.uint8) for leaf in jax.tree_util.tree_leaves(worlds)], 1)
        rows, seen = np.zeros((len(part), len(functions))), {}
        for i, row in enumerate(flat):
            key = row.tobytes()
            if key not in seen:
                world = jax.tree_util.tree_map(lambda leaf, i=i: leaf[i], worlds)
                seen[key] = np.array([f(world) for f in functions], np.float64)
            rows[i] = seen[key]
        return rows

    return describe


def pool_cache(store_path: Any, generator_fingerprint: str, seed: int) -> Path:
    """Where a generator's pool descriptors for ``seed`` are kept: ``pools/<fingerprint>-s<seed>.npz`` beside ``store.sqlite``.

    One file per generator and seed, whatever the event: the pool's latents are a prefix of one
    stream per seed (``analysis.pooled``), so every event and every pool size reads it.
    """
    return Path(store_path).parent / "pools" / f"{generator_fingerprint}-s{int(seed)}.npz"


def cached_describer(path: Any, describe: Callable[[np.ndarray], np.ndarray] | None) -> CachedDescriber:
    """``describe`` that keeps the longest pool prefix it described at ``path`` (``CachedDescriber``)."""
    return CachedDescriber(Path(path), describe)


class CachedDescriber:
    """``describe(z f64[n, dim]) -> f64[n, k]`` that keeps the longest pool prefix it described (its latents, descriptors
    and the seconds a row took) in one .npz, and describes only the rows past it; latents that differ from the kept
    ones are described afresh. A replay with no generator passes ``describe`` None: rows it does not hold are refused.
    """

    def __init__(self, path: Path, describe: Callable[[np.ndarray], np.ndarray] | None):
        self.path, self.describe = Path(path), describe

    def _load(self) -> tuple[np.ndarray | None, np.ndarray | None, float]:
        if not self.path.exists():
            return None, None, 0.0
        with np.load(self.path, allow_pickle=False) as stored:
            return stored["z"], stored["described"], float(stored["seconds_per_world"]) if "seconds_per_world" in stored.files else 0.0

    def held(self) -> int:
        """Rows kept (a prefix of the pool's stream when the latents match)."""
        return 0 if self._load()[0] is None else len(self._load()[0])

    def seconds_per_world(self) -> float:
        """What describing a row took when the kept rows were described (0 when none were)."""
        return self._load()[2]

    def __call__(self, z: np.ndarray) -> np.ndarray:
        import time

        from worldagent.files import write_atomically

        z = np.asarray(z, np.float64)
        held_z, held, per_world = self._load()
        shared = 0 if held_z is None else min(len(held_z), len(z))
        if held is None or held_z.shape[1:] != z.shape[1:] or not np.array_equal(held_z[:shared], z[:shared]):
            held, shared, per_world = None, 0, 0.0
        if shared == len(z):
            return held[: len(z)]
        if self.describe is None:
            raise WorldagentError(
                f"{self.path} (the pool's descriptors) is missing or stale; rerun `worldagent failure-rate` with the estimate's settings."
            )
        started = time.perf_counter()
        rest = np.asarray(self.describe(z[shared:]), np.float64).reshape(len(z) - shared, -1)
        per_world = (per_world * shared + time.perf_counter() - started) / len(z)
        described = rest if held is None else np.concatenate([held[:shared], rest])

        def save(tmp: Path) -> None:
            with open(tmp, "wb") as handle:
                np.savez(handle, z=z, described=described, seconds_per_world=per_world)

        write_atomically(self.path, save)
        return described
