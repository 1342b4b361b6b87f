"""The paper's phases iterated (issue 25 item 2): ``influence(..., rounds=N)``, ``--rounds N``.

Round 1 is the paper's experiment (``experiment.influence``). Each round r >= 2 does, per seed:
evaluate that seed's influenced agent of round r - 1 on fresh candidates (and the search, if any:
the same budgets, pushed toward the property; seeded ``round_seed``, never the evaluation worlds'
seed); add the worlds where it has the property to the worlds that agent trained on (repeats
kept once: what earlier agents failed on stays in); train
a fresh influenced agent on them, with the same algorithm, budget and seed. Fresh, not continued:
every round's agent has the default agent's training budget, so each round compares at equal
training cost, and the default agents are round 1's (their distribution never changes). Every
round's agents are evaluated on round 1's evaluation worlds, with the same episode keys::

    run_dir/round-<r>/influenced_worlds-s<seed>.npz   seed's training worlds in round r
    run_dir/round-<r>/agents/influenced-s<seed>/       trainer run dirs (+ trained.json when done)
    run_dir/round-<r>/influence.json                   round 1's default against round r's influenced agents
    run_dir/store.sqlite                               round-<r>-s<seed>-candidates / -search,
                                                       influence-eval-round<r>-influenced-s<seed>-...

Every step is cached as round 1's is (campaigns in the store, ``trained.json``, checkpoints), so
a killed run resumes at the round, campaign and training chunk it reached.
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import numpy as np

from worldagent.files import write_text
from worldagent.influence.cache import WORLDS_FILE, load_influenced_worlds, save_influenced_worlds
from worldagent.influence.confirmation import confirm_selection
from worldagent.influence.experiment import (
    RESULT_FILE,
    compare_agents,
    failure_event,
    round_result,
    search_worlds,
    selecting_setup,
    trained_policies,
    value_ranges,
)
from worldagent.influence.statistics import json_safe
from worldagent.influence.training import train_agents
from worldagent.influence.worlds import selected_evaluations, stacked


def round_dir(run_dir: Path, r: int) -> Path:
    """Where round ``r`` keeps its files (round 1: the run directory itself)."""
    return Path(run_dir) if r == 1 else Path(run_dir) / f"round-{r}"


def worlds_file(seed: int) -> str:
    """A later round's training worlds of one seed."""
    return f"influenced_worlds-s{seed}.npz"


def round_seed(seed: int, r: int) -> int:
    """Seed of round ``r``'s candidates and search: round 1's ``seed``, then seed + 2, + 4, ... (the
    evaluation worlds use seed + 1, so no round trains on them)."""
    return int(seed) + 2 * (int(r) - 1)


def round_campaigns(r: int, seed: int) -> tuple[str, str]:
    """(candidates, search) campaign names of round ``r``'s search with seed ``seed``'s agent."""
    return f"round-{r}-s{seed}-candidates", f"round-{r}-s{seed}-search"


def merge_worlds(spec, old: tuple, new: tuple | None) -> tuple:
    """``old`` worlds (worlds, latents, values) with ``new`` ones appended, each distinct world once (its first copy)."""
    if new is None:
        return old
    a, b = (spec.world_to_arrays(worlds) for worlds in (old[0], new[0]))
    joined = {k: np.concatenate([a[k], b[k]]) for k in a}
    seen, keep = set(), []
    for i in range(len(old[1]) + len(new[1])):
        digest = hashlib.sha256(b"".join(np.ascontiguousarray(joined[k][i]).tobytes() for k in sorted(joined))).digest()
        if digest not in seen:
            seen.add(digest)
            keep.append(i)
    latents = np.concatenate([old[1], new[1]])[keep]
    values = {m: np.concatenate([old[2][m], new[2][m]])[keep] for m in old[2]}
    return spec.world_from_arrays({k: v[keep] for k, v in joined.items()}), latents, values


def later_rounds(
    run_dir: Path, job: dict, settings: dict, seeds: list[int], default: dict, rounds: int, greedy: bool, runs_per_program, progress: bool
) -> list[dict]:
    """Rounds 2..``rounds`` after round 1 in ``run_dir``; each round's summary (its ``influence.json`` in full).

    ``job``: spec, env, params, G, selection, algo, config, options, counts of round 1;
    ``default``: round 1's default agents' {seed: {metric: mean}}.
    """
    from worldagent.store import RunStore

    spec = job["spec"]
    shared = load_influenced_worlds(run_dir, spec, WORLDS_FILE)
    pools = {s: shared for s in seeds}  # round 1's influenced worlds are every seed's
    summaries = []
    with RunStore(run_dir) as store:
        for r in range(2, rounds + 1):
            result = one_round(store, Path(run_dir), r, job, settings, seeds, pools, default, greedy, runs_per_program, progress)
            summaries.append(
                {
                    "round": r,
                    "dir": f"round-{r}",
                    "worlds": result["worlds"],
                    "summary": result["summary"],
                    "failed_training": result["failed_training"],
                }
            )
    return summaries


def one_round(
    store, run_dir: Path, r: int, job: dict, settings: dict, seeds: list[int], pools: dict, default: dict, greedy, runs_per_program, progress
) -> dict:
    """Round ``r``: search with round r - 1's influenced agents, grow each seed's worlds (``pools``, updated), retrain, evaluate."""
    from worldagent.agents.distributions import WorldPool

    spec, selection, counts = job["spec"], job["selection"], job["counts"]
    started, here, before = time.perf_counter(), round_dir(run_dir, r), round_dir(run_dir, r - 1)
    previous = trained_policies({f"influenced-s{s}": before / "agents" / f"influenced-s{s}" / "policy" for s in seeds}, spec, greedy)
    timings, tried, selected, added, campaigns, confirmed = {"search": 0.0}, 0, {}, {}, [], {}
    for s in seeds:
        clock = time.perf_counter()
        names = round_campaigns(r, s)
        fresh = {**counts, "seed": round_seed(counts["seed"], r)}
        evaluated, used, _ = search_worlds(
            store, spec, job["env"], job["params"], previous[f"influenced-s{s}"], job["G"], selection, fresh, progress, names
        )
        picks = selected_evaluations(store, used, selection, spec) if selection.mask(evaluated).any() else []  # none: the agent no longer fails there
        if picks and counts.get("confirm"):
            setup = selecting_setup(spec, job["env"], job["params"], previous[f"influenced-s{s}"], job["G"], counts, job.get("backend"))
            name = f"influence-round{r}-s{s}:{selection.text}"
            failure = failure_event(spec)
            picks, confirmed[str(s)] = confirm_selection(
                store, setup, picks, selection, repeats=counts["confirm"], seed=fresh["seed"], name=name, failure=failure, progress=progress
            )
        found = stacked(picks, selection, spec) if picks else None
        before_count = len(pools[s][1])
        pools[s] = merge_worlds(spec, pools[s], found)
        save_influenced_worlds(here / worlds_file(s), spec, *pools[s])
        selected[str(s)] = 0 if found is None else len(found[1])
        added[str(s)] = len(pools[s][1]) - before_count
        tried, campaigns = tried + len(evaluated), campaigns + used
        timings["search"] += time.perf_counter() - clock
    described = lambda s: f"{len(pools[s][1])} worlds with {selection.describe()} (round {r})"  # noqa: E731
    jobs = {f"influenced-s{s}": (here / "agents" / f"influenced-s{s}", s, WorldPool.create(pools[s][0]), described(s)) for s in seeds}
    agents, timings["train"] = train_agents(
        jobs, spec, job["algo"], job["config"], job["options"], job["params"], runs_per_program, progress, job.get("backend")
    )
    clock = time.perf_counter()
    policies = trained_policies({name: here / "agents" / name / record["policy"] for name, record in agents.items()}, spec, greedy)
    influenced = compare_agents(store, spec, job["env"], job["params"], job["G"], policies, counts, progress, prefix=f"round{r}-")["influenced"]
    timings["evaluate"] = time.perf_counter() - clock
    timings["total"] = time.perf_counter() - started
    worlds = {
        "tried": tried,
        "selected": selected,  # per seed: distinct worlds with the property among this round's
        "added": added,  # per seed: those of them not already in its training worlds
        "training_worlds": {str(s): len(pools[s][1]) for s in seeds},
        "campaigns": campaigns,
        "selected_values": {str(s): value_ranges(pools[s][2]) for s in seeds},
        **({"confirmation": confirmed} if confirmed else {}),  # per seed: how many of its agent's raw selection survived
    }
    result = round_result(spec, job["algo"], selection, settings, worlds, {"default": default, "influenced": influenced}, agents, "agents", timings)
    result["round"] = r
    result["files"] = {"store": "../store.sqlite", "worlds": [worlds_file(s) for s in seeds], "default_agents": "../agents"}
    write_text(here / RESULT_FILE, json.dumps(json_safe(result), indent=1))
    return result
