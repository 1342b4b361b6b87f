"""Campaigns over given worlds instead of latents (DESIGN.md "Named world sets"; ``worldagent evaluate worlds``).

A world set is a batch of worlds from a dataset file (``worldagent dataset``), the explorer's exports (one-world
dataset files), or a named set an ``EnvSpec`` declares (``world_sets``). Its campaign is stored as every other:
world i is slot i of generation 0, played with the keys of ``stored_seed(campaign, 0, i)``, committed batch by
batch, resumed by a rerun. Worlds have no latent unless a generator places them (the encoder's mean of each
world's cells), which is what puts them on the explorer's map.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.envs.registry import EnvSpec
from worldagent.errors import WorldagentError
from worldagent.evaluation.backends import LocalBackend, split
from worldagent.progress import progress_bar
from worldagent.search.campaign import Outcome, campaign_stream, check_repeats, stored_seed
from worldagent.search.objectives import Objective, play_outcomes, search_keys
from worldagent.store import Evaluation, RunStore

SET_BATCH = 64  # worlds evaluated (and committed) at a time
OPTIMISER = "given"  # what the store records as the campaign's optimiser: nothing chose these worlds
ENCODER_LATENTS = "encoder means"  # the latents recorded for worlds a generator placed


@dataclass(frozen=True)
class WorldSet:
    """Worlds to score agents on, as given.

    Attributes:
        worlds: the batched world pytree (numpy, leading axis W).
        labels: W short names, one per world (``maze.npz[3] (seed 17)``, ``prefabs[0]``).
        tag: a short name for its campaign: the set's name, or the first file's stem and a hash of the worlds.
        fingerprint: sha256 (16 hex digits) of the worlds' cells: a rerun resumes only on the same worlds.
    """

    worlds: Any
    labels: tuple[str, ...]
    tag: str
    fingerprint: str

    def __len__(self) -> int:
        return len(self.labels)


def cells_fingerprint(spec: EnvSpec, worlds: Any) -> str:
    """sha256 (16 hex digits) of the env's name and the worlds' cells."""
    digest = hashlib.sha256(spec.name.encode())
    digest.update(np.ascontiguousarray(np.asarray(spec.cells(worlds), np.uint8)).tobytes())
    return digest.hexdigest()[:16]


def count_of(worlds: Any) -> int:
    return int(np.shape(jax.tree_util.tree_leaves(worlds)[0])[0])


def is_file_name(text: str) -> bool:
    """``text`` names a file rather than a set: it ends in ``.npz`` or is a path on disk."""
    return text.lower().endswith(".npz") or Path(text).exists()


def named_set(spec: EnvSpec, name: str) -> WorldSet:
    """The world set ``name`` of ``spec.world_sets``, checked world by world; unknown names list the known ones."""
    if name not in spec.world_sets:
        known = ", ".join(spec.world_sets) or "none"
        raise WorldagentError(
            f"--worlds {name!r} is neither a .npz file nor a named world set of {spec.name} (its sets: {known}); "
            "pass a dataset file (`worldagent dataset`, or a world the explorer exported) or one of its sets."
        )
    worlds = jax.tree_util.tree_map(np.asarray, spec.world_sets[name]())
    if not isinstance(worlds, spec.world_type) or count_of(worlds) < 1:
        raise WorldagentError(
            f"{spec.name}'s world set {name!r} is not a non-empty batch of {spec.world_type.__name__}; fix its EnvSpec.world_sets entry."
        )
    env, _ = spec.make_env()
    for index in range(count_of(worlds)):
        try:
            env.check_world(jax.tree_util.tree_map(lambda leaf, i=index: leaf[i], worlds))
        except WorldagentError as error:
            raise WorldagentError(
                f"world {index} of {spec.name}'s set {name!r} is invalid ({error}); `worldagent check {spec.name}` checks every set."
            ) from None
    return WorldSet(worlds, tuple(f"{name}[{i}]" for i in range(count_of(worlds))), name, cells_fingerprint(spec, worlds))


def file_set(spec: EnvSpec, paths: Sequence[Path | str]) -> WorldSet:
    """The worlds of dataset files (``worldagent dataset``, or one-world files the explorer saves), in order."""
    from worldagent.worlds.dataset import WorldDataset

    sets = [(Path(path), WorldDataset.load(path, spec.name)) for path in paths]
    worlds = jax.tree_util.tree_map(lambda *leaves: np.concatenate([np.asarray(leaf) for leaf in leaves]), *(d.worlds for _, d in sets))
    labels = tuple(f"{path.name}[{i}]" + (f" (seed {seed})" if seed >= 0 else "") for path, data in sets for i, seed in enumerate(data.seeds))
    fingerprint = cells_fingerprint(spec, worlds)
    more = f"+{len(sets) - 1}" if len(sets) > 1 else ""
    return WorldSet(worlds, labels, f"{sets[0][0].stem}{more}-{fingerprint[:8]}", fingerprint)


def world_set(spec: EnvSpec, given: Sequence[str]) -> WorldSet:
    """The worlds ``--worlds`` names: dataset files (one or more), or one named set of ``spec``."""
    given = [str(text) for text in given]
    if not given:
        raise WorldagentError("no worlds given; pass --worlds FILE.npz (repeatable) or --worlds NAME (a named set; `worldagent envs` lists them).")
    files = [text for text in given if is_file_name(text)]
    if not files:
        if len(given) > 1:
            raise WorldagentError(f"--worlds names {len(given)} sets; evaluate one named set at a time (or give dataset files).")
        return named_set(spec, given[0])
    if len(files) != len(given):
        named = next(text for text in given if text not in files)
        raise WorldagentError(f"--worlds mixes files with {named!r}, which is no .npz file; pass either dataset files or one named set.")
    return file_set(spec, files)


def encoder_latents(spec: EnvSpec, generator: Any, worlds: Any) -> np.ndarray:
    """f64[W, dim]: where ``generator``'s encoder places each world (the mean of its posterior over z)."""
    cells = np.asarray(spec.cells(worlds), np.float32)
    return np.concatenate([np.asarray(generator.encode(jnp.asarray(cells[start : start + 1024]))) for start in range(0, len(cells), 1024)]).astype(
        np.float64
    )


class GivenWorlds:
    """``evaluate(indices f[n, 1], seeds[n]) -> [Outcome]``: the agents on given worlds, by index (a backend's callable).

    Args:
        objective: the metric that scores each world.
        env, params: the environment; policy: the agents; worlds: the batched worlds; repeats: episodes per world.
        keys_of: ``(seed, repeats) -> keys``: a search's episodes (default) or confirmation's.
    """

    def __init__(self, objective: Objective, env: Any, policy: Any, worlds: Any, repeats: int, params: Any, keys_of: Any = search_keys):
        self.objective, self.env, self.policy, self.worlds = objective, env, policy, worlds
        self.repeats, self.params, self.keys_of = int(repeats), params, keys_of

    def __call__(self, indices: np.ndarray, seeds: np.ndarray) -> list[Outcome]:
        picks = np.asarray(indices, np.int64).reshape(-1)
        worlds = jax.tree_util.tree_map(lambda leaf: np.asarray(leaf)[picks], self.worlds)
        return play_outcomes(self.objective, self.env, self.policy, worlds, seeds, self.repeats, self.params, keys_of=self.keys_of)


def check_placement(store: RunStore, name: str, placed: str) -> None:
    """A stored campaign of the same worlds must have placed them the same way (by a generator's encoder, or not)."""
    existing = store.campaign(name)
    if existing is not None and existing.config.get("latents") != placed:
        had = (
            "placed its worlds with a generator's encoder"
            if existing.config.get("latents") == ENCODER_LATENTS
            else "stored its worlds without latents"
        )
        now = "with --generator" if placed == ENCODER_LATENTS else "without --generator"
        raise WorldagentError(f"campaign {name!r} in {store.path} {had}; rerun it as it was started, not {now}, or pass another --out.")


def run_given(
    store: RunStore,
    name: str,
    evaluate: GivenWorlds,
    given: WorldSet,
    *,
    seed: int,
    agent: dict | None,
    latents: np.ndarray | None = None,
    backend: Any = None,
    progress: bool = True,
) -> list[Evaluation]:
    """Score every world of ``given`` into campaign ``name`` (resumed when it exists); returns its evaluations in world order.

    Args:
        store: the run store; name: the campaign.
        evaluate: ``GivenWorlds`` over ``given.worlds``.
        seed: the episodes' seed (world i plays with ``stored_seed(campaign, 0, i)``'s keys).
        agent: ``agents.policy.agent_record`` of the agents (a campaign resumes only with the same files).
        latents: f64[W, dim] where a generator placed the worlds, or None (stored without latents).
        backend: where batches are evaluated (``evaluation.backends``; None: here).
    """
    placed = ENCODER_LATENTS if latents is not None else "none"
    check_placement(store, name, placed)
    config = {
        "dim": 0 if latents is None else int(latents.shape[1]),
        "worlds": {"tag": given.tag, "count": len(given), "fingerprint": given.fingerprint},
        "latents": placed,
        **({"agent": agent} if agent else {}),
        "stream": campaign_stream(name),
    }
    spec = evaluate.objective
    campaign = store.open_campaign(name, spec.env, spec.metric, spec.maximize, OPTIMISER, len(given), seed, config, resume=True)
    stored = store.evaluations(name)
    check_repeats(name, store.path, stored, evaluate.repeats)
    done = {e.slot for e in stored}
    missing = [i for i in range(len(given)) if i not in done]
    backend = backend or LocalBackend()
    seeds = {slot: stored_seed(campaign, 0, slot) for slot in missing}
    batches = [
        (slots, np.asarray(slots, np.float64)[:, None], np.array([seeds[s] for s in slots])) for slots in split(missing, backend.workers, SET_BATCH)
    ]
    with progress_bar(f"{spec.metric} on {len(given):,} given worlds", total=len(given), enabled=progress) as advance:
        advance(len(given) - len(missing))
        started = time.time()
        for slots, outcomes in backend.run(evaluate, batches):  # committed as each batch arrives
            for slot, outcome in zip(slots, outcomes):
                latent = latents[slot] if latents is not None else np.zeros(0)
                store.add(campaign, 0, slot, latent, outcome.score, outcome.episodes, started, outcome.world)
            advance(len(slots))
            started = time.time()
    return sorted(store.evaluations(name), key=lambda e: e.slot)
