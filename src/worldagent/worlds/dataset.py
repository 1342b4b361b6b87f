"""Datasets of procedurally generated worlds (paper §5.2.1: 10,000 per environment).

A dataset file is one ``.npz`` (loaded with ``allow_pickle=False``) holding::

    format_version  int, FORMAT_VERSION
    env             str, the registered environment's name (see ``registry.names()``)
    seeds           int64[N], the generator seed of each world
    cells           uint8[N, D], each world's binary VAE input (``EnvSpec.cells``)
    cell_shape      int[...], the shape of one world's cells before flattening
    world/<field>   the world pytree's fields, each with leading axis N

Loading checks all of it and says what is wrong; nothing is unpickled.
"""

from __future__ import annotations

import dataclasses
import hashlib
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from worldagent.envs import registry
from worldagent.envs.registry import EnvSpec
from worldagent.errors import WorldagentError
from worldagent.files import write_atomically

FORMAT_VERSION = 1
GENERATION_CHUNK = 1000  # worlds generated per progress-bar tick


@dataclass(frozen=True)
class WorldDataset:
    """Worlds, their VAE cells and their seeds.

    Attributes:
        env: the environment's registered name (``registry.get(env)`` is its spec).
        seeds: int64[N] generator seeds; world i is ``spec.generate([seeds[i]])``.
        worlds: the batched world pytree (numpy arrays, leading axis N).
        cells: uint8[N, D] binary VAE input.
        cell_shape: shape of one world's cells before flattening.
    """

    env: str
    seeds: np.ndarray
    worlds: Any
    cells: np.ndarray
    cell_shape: tuple[int, ...]

    def __len__(self) -> int:
        return len(self.seeds)

    @property
    def fingerprint(self) -> str:
        """Short sha256 of the env and the cells: ties a trained VAE to the data it saw."""
        digest = hashlib.sha256(self.env.encode())
        digest.update(np.ascontiguousarray(self.cells).tobytes())
        return digest.hexdigest()[:16]

    def world(self, index: int) -> Any:
        """World ``index`` (no batch axis)."""
        return _map_fields(self.worlds, lambda leaf: leaf[index])

    def subset(self, indices) -> WorldDataset:
        """The worlds at ``indices`` as a dataset of their own."""
        indices = np.asarray(indices)
        return WorldDataset(self.env, self.seeds[indices], _map_fields(self.worlds, lambda x: x[indices]), self.cells[indices], self.cell_shape)

    def save(self, path: Path | str) -> Path:
        """Write the dataset to ``path`` (``.npz``) atomically."""
        arrays = {
            "format_version": np.int64(FORMAT_VERSION),
            "env": np.str_(self.env),
            "seeds": self.seeds,
            "cells": self.cells,
            "cell_shape": np.asarray(self.cell_shape, np.int64),
        }
        arrays.update({f"world/{name}": np.asarray(value) for name, value in _fields(self.worlds).items()})

        def save(tmp: Path) -> None:
            with open(tmp, "wb") as handle:  # a handle: np.savez would append ".npz" to a path
                np.savez_compressed(handle, **arrays)

        return write_atomically(path, save)

    @classmethod
    def load(cls, path: Path | str, env: str | EnvSpec | None = None) -> WorldDataset:
        """Read and check a dataset file; ``env`` (a name or a spec), if given, must match the file's."""
        path = Path(path)
        env = None if env is None else registry.get(env).name
        remedy = f"make it again with `worldagent dataset {env or '|'.join(registry.names())} --out {path}`"
        if not path.is_file():
            raise WorldagentError(f"dataset file {path} does not exist; {remedy}.")
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {name: data[name] for name in data.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as error:
            raise WorldagentError(f"dataset file {path} is corrupted or not a worldagent dataset ({type(error).__name__}); {remedy}.") from None
        return cls._from_arrays(arrays, path, env, remedy)

    @classmethod
    def _from_arrays(cls, arrays: dict, path: Path, env: str | None, remedy: str) -> WorldDataset:
        missing = {"format_version", "env", "seeds", "cells", "cell_shape"} - set(arrays)
        if missing:
            raise WorldagentError(f"dataset file {path} lacks {', '.join(sorted(missing))}; {remedy}.")
        version = int(arrays["format_version"])
        if version != FORMAT_VERSION:
            raise WorldagentError(f"dataset file {path} has format version {version}, this worldagent reads version {FORMAT_VERSION}; {remedy}.")
        file_env = str(arrays["env"])
        if env is not None and env != file_env:
            raise WorldagentError(f"dataset file {path} holds {file_env} worlds, not {env} worlds; pass a {env} dataset.")
        try:
            spec = registry.get(file_env)
        except WorldagentError as error:
            raise WorldagentError(f"dataset file {path}: {error}") from None
        seeds, cells = arrays["seeds"], arrays["cells"]
        cell_shape = tuple(int(s) for s in arrays["cell_shape"])
        fields = {name[len("world/") :]: value for name, value in arrays.items() if name.startswith("world/")}
        expected = {f.name for f in dataclasses.fields(spec.world_type)}
        if set(fields) != expected:
            raise WorldagentError(f"dataset file {path} has world fields {sorted(fields)}, expected {sorted(expected)}; {remedy}.")
        n = len(seeds)
        if n == 0:
            raise WorldagentError(f"dataset file {path} holds no worlds; pass a file with at least one ({remedy}).")
        bad = [name for name, value in fields.items() if len(value) != n]
        if seeds.ndim != 1 or cells.shape != (n, int(np.prod(cell_shape))) or bad or cell_shape != tuple(spec.cell_shape):
            raise WorldagentError(
                f"dataset file {path} is inconsistent (seeds {seeds.shape}, cells {cells.shape}, cell shape {cell_shape}, "
                f"fields of the wrong length: {bad or 'none'}); {remedy}."
            )
        worlds = spec.world_type(**fields)
        dataset = cls(file_env, seeds.astype(np.int64), worlds, cells.astype(np.uint8), cell_shape)
        if not np.array_equal(spec.cells(worlds), dataset.cells):
            raise WorldagentError(f"dataset file {path} has cells that do not match its worlds; {remedy}.")
        return dataset


def make_dataset(env: str | EnvSpec, n: int, seed: int, progress: bool = True) -> WorldDataset:
    """Generate ``n`` worlds of ``env`` with seeds ``seed, seed+1, ...`` (paper §5.2.1).

    Args:
        env: a registered environment's name, or its ``EnvSpec``.
        n: number of worlds (the paper: 10,000).
        seed: first generator seed.
        progress: show a progress bar.

    Returns:
        The dataset: ``seeds`` int64[n], ``worlds`` (leading axis n), ``cells`` uint8[n, D].
    """
    spec = registry.get(env)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise WorldagentError(f"n={n!r}; ask for at least 1 world.")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise WorldagentError(f"seed={seed!r}; pass a non-negative integer.")
    seeds = int(seed) + np.arange(int(n), dtype=np.int64)
    chunks = []
    from worldagent.progress import progress_bar

    with progress_bar(f"generating {n:,} {spec.name} worlds", total=n, enabled=progress) as advance:
        for start in range(0, n, GENERATION_CHUNK):
            chunks.append(spec.generate(seeds[start : start + GENERATION_CHUNK]))
            advance(len(seeds[start : start + GENERATION_CHUNK]))
    worlds = _map_fields(chunks[0], lambda *leaves: np.concatenate([np.asarray(leaf) for leaf in leaves]), *chunks[1:])
    return WorldDataset(spec.name, seeds, worlds, np.asarray(spec.cells(worlds), np.uint8), tuple(spec.cell_shape))


def _fields(world: Any) -> dict[str, Any]:
    return {f.name: getattr(world, f.name) for f in dataclasses.fields(world)}


def _map_fields(world: Any, fn, *others: Any) -> Any:
    """Apply ``fn`` field by field to one or more worlds of the same type."""
    return type(world)(**{name: fn(value, *(_fields(o)[name] for o in others)) for name, value in _fields(world).items()})
