"""Searches that survive noise, compared at equal episode budgets on confirmed values (issue 50, item 4).

    python benchmarks/noisy_search.py --env racing --agent RUN/racing/agent --generator RUN/racing/generator \
        [--budget 210] [--seeds 0 1 2 3 4] [--work runs/noisy-search]
    python benchmarks/noisy_search.py --merge   # the per-env parts -> benchmarks/results/noisy-search.json

For each seed, every method minimises the env's main metric over the generator's latents with ``--budget``
evaluations of 8 episodes (re-evaluations count: they are evaluations), and its reported world is confirmed on
64 fresh episodes (``analysis.confirm``). Point searches: today's ``cmaes``, ``bo``, ``random``; ``cmaes-re``
(CMA-ES re-evaluating its incumbents) and ``bo-noise`` (a GP with a learned noise level, re-evaluating its
incumbent), whose reported world is the latent with the best mean over all its evaluations
(``optimisers.reported_evaluation``). Atlases on the env's default descriptors (10 × 10): today's CMA-ME,
``atlas-corrected`` (CMA-ME for 70% of the budget, then its elites re-evaluated) and ``atlas-adaptive``
(adaptive sampling); for these, up to ``--elites`` elites that the search calls failing (the env's failure
event) are confirmed on 32 fresh episodes each, and the confirmed failing cells counted.

Recorded per seed and method: the confirmed value of the reported world with its 95% interval, the found value
(the selection's, on its pooled episodes), whether the reported world is confirmed failing, the atlas's
failing cells (found and confirmed), and the episodes spent (search + confirmation). BO variants run with a
cheaper acquisition search than the default (``BO``), the same for both, to fit the machine's time; ``--bo library``
runs them with the library's defaults (``OptimiserConfig()``: what ``worldagent strategic`` and ``reproduce`` use).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import QUICK_RUN, RESULTS, describe_machine  # noqa: E402
from worldagent import experiments  # noqa: E402
from worldagent.agents.policy import agent_record  # noqa: E402
from worldagent.analysis.confirm import ELITE_REPEATS, REPEATS, confirm  # noqa: E402
from worldagent.files import write_text  # noqa: E402
from worldagent.search.atlas import QDOptimiser, archive_of, atlas_optimiser  # noqa: E402
from worldagent.search.campaign import CampaignSpec, run_campaign  # noqa: E402
from worldagent.search.noisy_atlas import noisy_atlas_optimiser  # noqa: E402
from worldagent.search.objectives import LatentObjective, Objective  # noqa: E402
from worldagent.search.optimisers import OptimiserConfig, make_optimiser, reported_evaluation  # noqa: E402
from worldagent.store import RunStore  # noqa: E402

POINT = ("cmaes", "bo", "random", "cmaes-re", "bo-noise")
ATLAS = ("atlas", "atlas-corrected", "atlas-adaptive")
BO = OptimiserConfig(bo_candidates=500, bo_starts=1, bo_gp_restarts=1)
BO_SETTINGS = {"benchmark": BO, "library": OptimiserConfig()}  # --bo
PART = "noisy-search-{env}.json"
# (a, b): confirmed value of a minus b per seed; the searches minimise, so negative means a found worse worlds
PAIRS = (
    ("cmaes-re", "cmaes"),
    ("bo-noise", "bo"),
    ("atlas-corrected", "atlas"),
    ("atlas-adaptive", "atlas"),
    ("cmaes", "random"),
    ("cmaes-re", "random"),
)


def objective_of(setup) -> LatentObjective:
    metric = setup.spec.metrics.main
    return LatentObjective(Objective(setup.spec.name, metric, False), setup.env, setup.policy, setup.generator, setup.repeats, setup.params)


def run_point(store, setup, method: str, budget: int, seed: int, bo: str = "benchmark"):
    """One point search (``bo``: BO's settings, a key of ``BO_SETTINGS``); returns (its evaluations, its reported evaluation)."""
    config = BO_SETTINGS[bo] if method.startswith("bo") else OptimiserConfig()
    dim = setup.generator.latent_dim
    name = f"{method}-s{seed}"
    spec = CampaignSpec(name, setup.spec.name, setup.spec.metrics.main, False, method, budget, seed, dim, config, agent=agent_record(setup.policy))
    optimiser = make_optimiser(method, dim, False, seed, config)
    found = run_campaign(store, spec, objective_of(setup), resume=True, progress=False, optimiser=optimiser)
    return found, reported_evaluation(found, False), None


def run_atlas(store, setup, method: str, budget: int, seed: int):
    """One atlas; returns (its evaluations, its reported evaluation, {cell: pooled elite evaluation})."""
    if method == "atlas":
        optimiser, extra = atlas_optimiser(setup.spec, setup.generator, False, seed, budget)
    else:
        optimiser, extra = noisy_atlas_optimiser(setup.spec, setup.generator, False, seed, budget, method.split("-")[1])
    name = f"{method}-s{seed}"
    dim = setup.generator.latent_dim
    spec = CampaignSpec(
        name, setup.spec.name, setup.spec.metrics.main, False, optimiser.name, budget, seed, dim, agent=agent_record(setup.policy), extra=extra
    )
    found = run_campaign(store, spec, objective_of(setup), resume=True, progress=False, optimiser=optimiser)
    pooled = pooled_by_latent(found)
    if type(optimiser) is QDOptimiser:
        archive = archive_of(optimiser.grid, np.array([e.score for e in found]), optimiser.describe(np.stack([e.latent for e in found])), False)
        cells = {int(c): found[int(i)] for c, i in zip(archive.cells, archive.best)}
    else:
        cells = {cell: pooled[latent.tobytes()] for cell, (latent, _, _) in optimiser.elites().items()}
    return found, reported_evaluation(found, False), cells


def pooled_by_latent(evaluations) -> dict:
    """{latent bytes: the latent's evaluations pooled (``reported_evaluation`` of them alone)}."""
    groups: dict = {}
    for e in evaluations:
        groups.setdefault(np.asarray(e.latent, np.float64).tobytes(), []).append(e)
    return {key: reported_evaluation(group, False) for key, group in groups.items()}


def one(store, setup, method: str, budget: int, seed: int, selection, elites: int, bo: str = "benchmark") -> dict:
    start = time.perf_counter()
    if method in ATLAS:
        found, reported, cells = run_atlas(store, setup, method, budget, seed)
    else:
        found, reported, cells = run_point(store, setup, method, budget, seed, bo)
    searched = time.perf_counter() - start
    metric = setup.spec.metrics.main
    [world] = confirm(store, setup, [reported], name=f"reported:{method}-s{seed}", repeats=REPEATS, seed=seed, progress=False)
    row = {
        "evaluations": len(found),
        "distinct_latents": len({e.latent.tobytes() for e in found}),
        "reported": {"generation": reported.generation, "slot": reported.slot, "evaluations": len(reported.episodes) // setup.repeats},
        "found": world.found(metric).as_dict(),
        "confirmed": world.confirmed(metric).as_dict(),
        "found_failure_rate": world.failure_rate(selection, confirmed=False).as_dict(),
        "confirmed_failure_rate": world.failure_rate(selection).as_dict(),
        "reported_confirmed_failing": world.holds(selection),
        "search_episodes": int(sum(len(e.episodes) for e in found)),
        "confirmation_episodes": world.repeats,
    }
    if cells is not None:
        failing = [cell for cell, e in cells.items() if selection.mask([e])[0]]
        failing.sort(key=lambda cell: cells[cell].score)
        checked = confirm(
            store, setup, [cells[c] for c in failing[:elites]], name=f"elites:{method}-s{seed}", repeats=ELITE_REPEATS, seed=seed, progress=False
        )
        row.update(
            cells=len(cells),
            found_failing_cells=len(failing),
            confirmed_cells=len(checked),
            confirmed_failing_cells=int(sum(c.holds(selection) for c in checked)),
            distinct_confirmed_failing_worlds=len({c.digest for c in checked if c.holds(selection)}),
        )
        row["confirmation_episodes"] += sum(c.repeats for c in checked)
    row["episodes"] = row["search_episodes"] + row["confirmation_episodes"]
    row["seconds"] = round(time.perf_counter() - start, 1)
    row["search_seconds"] = round(searched, 1)
    return row


def summarise(per_seed: dict, methods) -> dict:
    """Per method over seeds: mean confirmed value, mean found, seeds whose reported world is confirmed failing."""
    table = {}
    for method in methods:
        rows = [per_seed[s][method] for s in per_seed if method in per_seed[s]]
        if not rows:
            continue
        confirmed = np.array([r["confirmed"]["mean"] for r in rows])
        found = np.array([r["found"]["mean"] for r in rows])
        entry = {
            "seeds": len(rows),
            "confirmed_mean": round(float(confirmed.mean()), 4),
            "confirmed_sd": round(float(confirmed.std(ddof=1)), 4) if len(rows) > 1 else 0.0,
            "found_mean": round(float(found.mean()), 4),
            "winners_curse": round(float((confirmed - found).mean()), 4),
            "reported_confirmed_failing": int(sum(r["reported_confirmed_failing"] for r in rows)),
            "episodes_mean": round(float(np.mean([r["episodes"] for r in rows])), 1),
        }
        if "cells" in rows[0]:
            entry["found_failing_cells"] = int(sum(r["found_failing_cells"] for r in rows))
            entry["confirmed_failing_cells"] = int(sum(r["confirmed_failing_cells"] for r in rows))
        table[method] = entry
    return table


def paired(per_seed: dict, a: str, b: str) -> dict:
    """Confirmed value of ``a`` minus ``b``, seed by seed (negative: ``a`` found worse worlds)."""
    d = np.array(
        [per_seed[s][a]["confirmed"]["mean"] - per_seed[s][b]["confirmed"]["mean"] for s in per_seed if a in per_seed[s] and b in per_seed[s]]
    )
    if not len(d):
        return {}
    return {"mean": round(float(d.mean()), 4), "per_seed": [round(float(x), 4) for x in d], "a_lower": int((d < 0).sum()), "seeds": len(d)}


def run_env(args) -> None:
    work = args.work / args.env
    (work / "agent").exists() or shutil.copytree(args.agent, work / "agent")
    (work / "generator").exists() or shutil.copytree(args.generator, work / "generator")
    setup = experiments.setup(args.env, str(work / "agent"), work / "generator", repeats=8)
    selection = experiments.failure_selection(setup.spec.failure, setup.spec.name)
    methods = args.methods or (*POINT, *ATLAS)
    started = time.time()
    part = args.work / PART.format(env=args.env)
    per_seed = json.loads(part.read_text())["per_seed"] if part.exists() else {}
    with RunStore(work) as store:
        for seed in args.seeds:
            for method in methods:
                if method in per_seed.get(str(seed), {}):
                    continue
                row = one(store, setup, method, args.budget, seed, selection, args.elites, args.bo)
                per_seed.setdefault(str(seed), {})[method] = row
                print(
                    f"{args.env} s{seed} {method}: found {row['found']['mean']:.4g} confirmed {row['confirmed']['mean']:.4g} ({row['seconds']} s)",
                    flush=True,
                )
                write_text(part, json.dumps({"env": args.env, "per_seed": per_seed, "command": " ".join(sys.argv)}, indent=1))
    result = {
        "env": args.env,
        "agent": str(args.agent),
        "generator": str(args.generator),
        "failure": setup.spec.failure,
        "metric": setup.spec.metrics.main,
        "direction": "min",
        "budget": args.budget,
        "repeats": 8,
        "confirm_repeats": REPEATS,
        "elite_repeats": ELITE_REPEATS,
        "elites_confirmed_at_most": args.elites,
        "bo_config": {name: getattr(BO_SETTINGS[args.bo], name) for name in ("bo_candidates", "bo_starts", "bo_gp_restarts")},
        "command": " ".join(sys.argv),
        "wall_seconds_this_call": round(time.time() - started, 1),
        "machine": describe_machine(),
        "summary": summarise(per_seed, methods),
        "paired": {f"{a} - {b}": paired(per_seed, a, b) for a, b in PAIRS},
        "per_seed": per_seed,
    }
    write_text(part, json.dumps(result, indent=1))


def merge(args) -> None:
    """Every part under ``--work`` (an env may be split by seeds over several processes), one entry per env."""
    envs: dict = {}
    for path in sorted(args.work.glob("**/" + PART.format(env="*"))):
        data = json.loads(path.read_text())
        entry = envs.setdefault(data["env"], {"per_seed": {}, "commands": [], "wall_seconds_per_part": []})
        for seed, rows in data["per_seed"].items():  # a part stopped early keeps the seeds it finished
            entry["per_seed"].setdefault(seed, {}).update(rows)
        entry["commands"].append(data["command"])
        if "summary" in data:  # a finished part: the run's settings, its wall time
            entry.update({k: v for k, v in data.items() if k not in ("per_seed", "command", "wall_seconds_this_call", "summary", "paired")})
            entry["wall_seconds_per_part"].append(data["wall_seconds_this_call"])
    for entry in envs.values():
        entry["per_seed"] = dict(sorted(entry["per_seed"].items(), key=lambda item: int(item[0])))
        methods = [m for m in (*POINT, *ATLAS) if any(m in row for row in entry["per_seed"].values())]
        entry["summary"] = summarise(entry["per_seed"], methods)
        entry["paired"] = {f"{a} - {b}": paired(entry["per_seed"], a, b) for a, b in PAIRS}
    out = RESULTS / "noisy-search.json"
    result = {"benchmark": "noisy-search", "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "note": args.note, "envs": envs}
    write_text(out, json.dumps(result, indent=1))
    print(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env")
    parser.add_argument("--agent", type=Path)
    parser.add_argument("--generator", type=Path)
    parser.add_argument("--budget", type=int, default=210)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--methods", nargs="+")
    parser.add_argument("--elites", type=int, default=8, help="failing elites confirmed per atlas, at most")
    parser.add_argument("--work", type=Path, default=Path("runs/noisy-search"))
    parser.add_argument("--bo", choices=tuple(BO_SETTINGS), default="benchmark", help="BO's acquisition settings (see the docstring)")
    parser.add_argument("--merge", action="store_true")
    parser.add_argument("--note", default="", help="with --merge: what the JSON should say about the run (e.g. the machine's load)")
    args = parser.parse_args()
    if args.merge:
        merge(args)
    elif not (args.env and args.agent and args.generator):
        parser.error(
            f"--env, --agent and --generator are needed to search: `{QUICK_RUN}` writes them to runs/quick/ENV/agent and runs/quick/ENV/generator"
        )
    else:
        run_env(args)


if __name__ == "__main__":
    main()
