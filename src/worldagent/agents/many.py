"""Many runs, one program: N independent training runs as one vmapped, jitted, chunked loop (issue 28).

Seeds of one arm, and arms whose world distributions have the same shape (pools of different
sizes are padded with worlds never drawn), train together::

    runs = [ManyRun(out / f"seed{s}", seed=s, distribution=pool) for s in range(5)]
    results = train_many(spec, "ppo", config, runs)        # training.TrainResult per run, in order

Every run keeps what ``training.train`` writes for it (``run.json``, checkpoint, ``curve.csv``,
``curve.png``, the agent in ``policy/``), through the same helpers (``training.open_run``,
``record_chunk``, ``finish_run``), and resumes from its own checkpoint. Runs whose trainers share
a compiled core (``trainer.Program``: same algorithm, config but for DQN's budget, env) and
whose consts have one structure and shape form a group; a group of at most ``max_together`` runs
is one program, ``jit(vmap(chunk))`` over the runs' states and consts (consts all runs share are
passed once, not stacked), and groups run one after another; a group of one run is trained by
``training.train``'s own loop (``run_chunks``), as that run alone.

Equality with a run alone: each run starts exactly as alone (its own ``init``, not vmapped;
a vmapped orthogonal initialiser's batched QR also deadlocked XLA's CPU pool, jaxlib 0.10.2),
and its chunks compute the same function; XLA compiles the batched update with other loop
orders, so its floats differ from the run alone in the last bits (measured in
``tests/agents/test_many.py`` and ``benchmarks/many_runs.py``), and those differences grow
as training goes on. A resumed many-run continues bit-identically (the same program).

Across machines (``backend``, a Ray backend of ``evaluation.backends``): each program's runs go
to a Ray worker as one task, which trains them there exactly as here, writing their directories
(a shared filesystem on a multi-machine cluster); a task whose worker dies is retried by Ray and
resumes from the runs' checkpoints. The driver then finishes every run from its final checkpoint,
so what it returns is what a local many-run returns.

Cost: under ``vmap`` a ``lax.cond`` whose predicate differs by run runs both branches. A run whose
budget is spent keeps computing (and discarding) updates until its group is done; DQN computes
its learning step during the replay warm-up too; K-FAC's periodic re-inversion is mapped run by
run instead (``kfac._run_by_run``), so it stays periodic.
"""

from __future__ import annotations

import functools
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.agents.distributions import WorldPool
from worldagent.agents.training import OpenRun, TrainResult, checkpoint, finish_run, open_run, record_chunk, run_chunks, status
from worldagent.errors import WorldagentError
from worldagent.progress import progress_bar

MAX_TOGETHER = 64  # runs per program at most, whatever the memory: beyond, batching gains little


@dataclass(frozen=True)
class ManyRun:
    """One run of a many-run: what differs from the others (``training.train``'s arguments of the same names).

    Attributes:
        out_dir: the run directory.
        seed: the run's seed.
        distribution: its world distribution.
        distribution_spec: how the distribution was built, recorded in ``run.json``.
        params: the env params to train under (default: the env's).
    """

    out_dir: str | Path
    seed: int
    distribution: Any
    distribution_spec: str = ""
    params: Any = None


def device_memory() -> int:
    """Bytes of memory of the default device (host RAM for the CPU)."""
    stats = jax.devices()[0].memory_stats() or {}
    return int(stats.get("bytes_limit") or os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


def default_max_together(state_bytes: int, memory: int | None = None) -> int:
    """Runs per program by default: as many as fit a quarter of the device's memory at 8x a run's state
    (its rollouts, gradients and the chunk's double buffers), at most ``MAX_TOGETHER``."""
    memory = device_memory() if memory is None else memory
    return int(max(1, min(MAX_TOGETHER, memory // 4 // max(1, 8 * state_bytes))))


def pad_pool(pool: WorldPool, size: int) -> WorldPool:
    """``pool`` with copies of its last world appended up to ``size`` worlds, never drawn (probability 0,
    cdf 1), so every draw is the one the unpadded pool makes."""
    extra = size - pool.size
    if extra <= 0:
        return pool
    worlds = jax.tree_util.tree_map(lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], extra, axis=0)]), pool.worlds)
    return WorldPool(
        worlds, jnp.concatenate([pool.probs, jnp.zeros(extra, pool.probs.dtype)]), jnp.concatenate([pool.cdf, jnp.ones(extra, pool.cdf.dtype)])
    )


def _is_pool(x) -> bool:
    return isinstance(x, WorldPool)


def _program_args(runs: Sequence[OpenRun]) -> list[tuple]:
    """Each run's ``(budget, consts)``, its world pools padded to the largest pool of any run."""
    programs = [run.trainer.program for run in runs]
    if any(program is None for program in programs):
        raise WorldagentError("this algorithm's trainer has no trainer.Program; train its runs one by one with training.train.")
    pools = [x for p in programs for x in jax.tree_util.tree_leaves(p.consts, is_leaf=_is_pool) if _is_pool(x)]
    size = max((pool.size for pool in pools), default=0)
    pad = lambda consts: jax.tree_util.tree_map(lambda x: pad_pool(x, size) if _is_pool(x) else x, consts, is_leaf=_is_pool)  # noqa: E731
    return [(p.budget, pad(p.consts)) for p in programs]


def _group_key(run: OpenRun, args: tuple) -> tuple:
    """Runs with equal keys can share one program: the same compiled core, chunk size, consts structure and shapes."""
    leaves, treedef = jax.tree_util.tree_flatten(args)
    program = run.trainer.program
    return (program.init, program.chunk, run.chunk_updates, treedef, tuple((np.shape(x), jnp.asarray(x).dtype) for x in leaves))


def _same_leaf(leaves: list) -> bool:
    """All runs hold this leaf: the same object, or equal arrays (then it is passed once, not stacked)."""
    first = leaves[0]
    return all(x is first for x in leaves) or all(np.array_equal(np.asarray(first), np.asarray(x)) for x in leaves[1:])


@functools.lru_cache(maxsize=32)
def _vmapped_chunk(chunk, n: int, treedef, shared: tuple[bool, ...]):
    """``jit(vmap(chunk))`` over stacked states and the runs' own consts leaves; ``shared`` leaves are passed once."""

    def one(state, own, common):
        own, common = iter(own), iter(common)
        total, consts = jax.tree_util.tree_unflatten(treedef, [next(common) if s else next(own) for s in shared])
        return chunk(state, n, total, consts)

    return jax.jit(jax.vmap(one, in_axes=(0, 0, None)))


def _stack(trees: Sequence[Any]) -> Any:
    return jax.tree_util.tree_map(lambda *x: jnp.stack([jnp.asarray(v) for v in x]), *trees)


def _train_group(group: list[OpenRun], args: list[tuple], stop_after_chunks: int | None, advance) -> float:
    """Train one group as one program until every run's budget is spent (or ``stop_after_chunks``); its wall seconds."""
    if len(group) == 1:  # training.train's own program, not a vmap over one run (harvest's DQN: about 25% slower)
        return run_chunks(group[0], stop_after_chunks, advance)
    flat = [jax.tree_util.tree_flatten(a) for a in args]
    treedef = flat[0][1]
    columns = list(zip(*(leaves for leaves, _ in flat)))
    shared = tuple(_same_leaf(list(column)) for column in columns)
    own = [jnp.stack([jnp.asarray(x) for x in column]) for column, s in zip(columns, shared) if not s]
    common = [column[0] for column, s in zip(columns, shared) if s]
    program = group[0].trainer.program
    chunk = _vmapped_chunk(program.chunk, group[0].chunk_updates, treedef, shared)
    budgets = [int(run.config.episodes) for run in group]
    done = lambda run: bool(run.trainer.done(run.state))  # noqa: E731
    start, chunks, states = time.perf_counter(), 0, _stack([run.state for run in group])
    try:
        while not all(map(done, group)) and (stop_after_chunks is None or chunks < stop_after_chunks):
            chunks += 1
            before = [min(int(run.state.episodes), b) for run, b in zip(group, budgets)]
            states, curves = chunk(states, own, common)
            host_states, host_curves = jax.device_get((states, curves))
            elapsed = time.perf_counter() - start
            for i, run in enumerate(group):
                curve = {name: column[i] for name, column in host_curves.items()}
                if np.any(curve["active"] > 0):  # a finished run's chunk only skips: nothing to record
                    record_chunk(run, jax.tree_util.tree_map(lambda x, i=i: x[i], host_states), curve, elapsed)
            runs_status = status(group[0])
            advance(sum(min(int(run.state.episodes), b) for run, b in zip(group, budgets)) - sum(before), **runs_status)
    finally:
        for run in group:
            checkpoint(run)
    return time.perf_counter() - start


def train_many(
    spec: Any,
    algo: str,
    config: Any,
    runs: Sequence[ManyRun],
    *,
    options: dict | None = None,
    progress: bool = True,
    resume: bool = True,
    stop_after_chunks: int | None = None,
    chunk_updates: int | None = None,
    max_together: int | None = None,
    backend: Any = None,
) -> list[TrainResult]:
    """Train ``runs`` (seeds, arms) of one algorithm and config, as few vmapped programs as their shapes allow.

    Args:
        spec: the environment (an ``EnvSpec`` or its name).
        algo: a name in ``algorithms.ALGORITHMS``.
        config: the algorithm's config, shared by every run.
        runs: the runs (``ManyRun``: directory, seed, distribution, env params), directories distinct.
        options: the env's options, shared by every run.
        progress: show one progress bar (episodes of all runs).
        resume: each run continues from its own checkpoint if it has one (see ``training.train``).
        stop_after_chunks: stop each group after this many chunks (a time-boxed run; resumable).
        chunk_updates: updates per jitted chunk (default: the config's); every run's checkpoint
            is written as in ``training.train``.
        max_together: runs per program at most (memory); default ``default_max_together`` of a
            run's state size on the default device.
        backend: None or a local backend (train here), or a Ray backend
            (``evaluation.backends.make_backend("ray")``): each program is a task on a worker.

    Returns:
        One ``training.TrainResult`` per run, in order; ``wall_seconds`` is its group's.
    """
    if not runs:
        raise WorldagentError("train_many got no runs; pass at least one ManyRun.")
    directories = [Path(run.out_dir).resolve() for run in runs]
    if len(set(directories)) < len(directories):
        raise WorldagentError("two runs share an output directory; give each run its own out_dir.")
    if max_together is not None and (isinstance(max_together, bool) or not isinstance(max_together, (int, np.integer)) or max_together < 1):
        raise WorldagentError(f"max_together={max_together!r}; use at least 1.")
    open_one = lambda run, resume: open_run(  # noqa: E731
        spec, algo, config, run.distribution, run.out_dir, seed=run.seed, options=options, params=run.params, resume=resume,
        distribution_spec=run.distribution_spec, chunk_updates=chunk_updates,
    )  # fmt: skip
    opened = [open_one(run, resume) for run in runs]
    args = _program_args(opened)
    state_bytes = sum(np.asarray(x).nbytes for x in jax.tree_util.tree_leaves(opened[0].state))
    cap = int(max_together or default_max_together(state_bytes))
    groups: dict[tuple, list[int]] = {}
    for i, run in enumerate(opened):
        groups.setdefault(_group_key(run, args[i]), []).append(i)
    batches = [members[at : at + cap] for members in groups.values() for at in range(0, len(members), cap)]
    walls = [0.0] * len(opened)
    if getattr(backend, "name", "local") == "ray":
        tasks = [(spec, algo, config, [runs[i] for i in batch], options, chunk_updates) for batch in batches]
        for batch, wall in zip(batches, backend.map(_train_batch, tasks, f"training {len(runs)} {algo} runs on Ray", progress)):
            for i in batch:
                walls[i] = wall
        finished = [open_one(run, True) for run in runs]  # each run's final checkpoint, as the workers left it
        return [finish_run(run, wall) for run, wall in zip(finished, walls)]
    total = sum(int(run.config.episodes) for run in opened)
    title = f"training {len(opened)} {algo} runs on {opened[0].spec.name}"
    with progress_bar(title, total=total, enabled=progress) as advance:
        advance(sum(min(int(run.state.episodes), int(run.config.episodes)) for run in opened))
        for batch in batches:
            wall = _train_group([opened[i] for i in batch], [args[i] for i in batch], stop_after_chunks, advance)
            for i in batch:
                walls[i] = wall
    return [finish_run(run, wall) for run, wall in zip(opened, walls)]


def _train_batch(spec, algo: str, config, runs: list[ManyRun], options, chunk_updates) -> float:
    """A Ray task: one program's runs trained on this worker (resuming their checkpoints); its wall seconds."""
    results = train_many(spec, algo, config, runs, options=options, progress=False, resume=True, chunk_updates=chunk_updates, max_together=len(runs))
    return results[0].wall_seconds
