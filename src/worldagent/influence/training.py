"""Step (c) of influencing: the agents trained, as few programs as their shapes allow (``many.train_many``).

Each agent keeps its own run directory (checkpoint, curve, ``policy/``); ``trained.json`` marks a
finished one, so a rerun neither compiles nor rewrites it, and an unfinished one resumes from its
checkpoint.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import jax
import numpy as np

from worldagent.agents.training import CURVE_FILE, read_curve
from worldagent.errors import WorldagentError
from worldagent.events import Selection
from worldagent.files import write_text
from worldagent.influence.cache import TRAINED_FILE

LABELS = ("default", "influenced")


def trained_record(out: Path) -> dict | None:
    """The record of a finished agent (its ``trained.json``), None while it is unfinished."""
    marker = out / TRAINED_FILE
    return json.loads(marker.read_text()) if marker.is_file() else None


def mark_trained(out: Path, result: Any, seed: int, described: str) -> dict:
    """Write ``out/trained.json`` after its trainer returned (a rerun then neither compiles nor rewrites the agent).
    Its ``wall_seconds`` is the whole training's, resumes included: the learning curve's clock."""
    rows = read_curve(out / CURVE_FILE)
    seconds = rows[-1]["wall_seconds"] if rows else result.wall_seconds
    record = {"policy": "policy", "episodes": result.episodes, "env_steps": result.env_steps, "wall_seconds": round(seconds, 3)}
    write_text(out / TRAINED_FILE, json.dumps({**record, "seed": int(seed), "distribution": described}, indent=1))
    return trained_record(out)


def default_runs_per_program() -> int | None:
    """Agents trained as one program by default: 2 on a CPU, where one run already keeps the cores
    busy and a larger program is no faster (``benchmarks/results/many-runs.json``); elsewhere None,
    ``many.train_many``'s default from the device's memory."""
    return 2 if jax.default_backend() == "cpu" else None


def check_runs_per_program(value: Any) -> int | None:
    """``runs_per_program``: None (from the device) or a positive integer."""
    if value is not None and (isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1):
        raise WorldagentError(f"runs_per_program={value!r}; pass a positive number of agents per program (--runs-per-program).")
    return value


def train_agents(
    jobs: dict[str, tuple], spec, algo: str, config: Any, options: Any, params: Any, runs_per_program: int | None, progress: bool, backend: Any = None
):
    """Train the unfinished of ``jobs`` ({name: (out dir, seed, distribution, described)}) as few programs as
    their shapes allow (``many.train_many``: seeds together, and arms whose pools pad to one shape),
    each resuming its own checkpoint, here or (``backend``: Ray) each program as a task on a worker;
    returns ({name: record}, {name: seconds of its program})."""
    from worldagent.agents.many import ManyRun, train_many

    records = {name: trained_record(job[0]) for name, job in jobs.items()}
    pending = [name for name, record in records.items() if record is None]
    timings = {name: 0.0 for name in jobs}
    if pending:
        runs = [ManyRun(jobs[n][0], seed=int(jobs[n][1]), distribution=jobs[n][2], distribution_spec=jobs[n][3], params=params) for n in pending]
        cap = runs_per_program if runs_per_program is not None else default_runs_per_program()
        results = train_many(spec, algo, config, runs, options=options, progress=progress, resume=True, max_together=cap, backend=backend)
        for name, result in zip(pending, results):
            records[name] = mark_trained(jobs[name][0], result, jobs[name][1], jobs[name][3])
            timings[name] = result.wall_seconds
    return records, timings


def train_all(
    run_dir: Path,
    spec,
    algo: str,
    config,
    G,
    worlds,
    selection: Selection,
    seeds: list[int],
    options,
    params,
    progress: bool,
    runs_per_program=None,
    backend: Any = None,
):
    """Step (c): one default and one influenced agent per seed, same algorithm, budget and seed; (records, timings)."""
    from worldagent.agents.distributions import LatentWorlds, WorldPool

    count = len(jax.tree_util.tree_leaves(worlds)[0])
    distributions = {
        "default": (LatentWorlds(G), "G(z), z ~ N(0, I)"),
        "influenced": (WorldPool.create(worlds), f"{count} worlds with {selection.describe()}"),
    }
    jobs = {f"{label}-s{s}": (run_dir / "agents" / f"{label}-s{s}", s, *distributions[label]) for s in seeds for label in LABELS}
    return train_agents(jobs, spec, algo, config, options, params, runs_per_program, progress, backend)
