"""The failure atlas against CMA-ES and random search at the same budget (issue 15, item 1).

    python benchmarks/studies/atlas_comparison.py --run runs/quick [--budget 2100] [--seeds 0 1 2]

For each seed, three campaigns minimise the racing return of the run's agent on its generator,
``--budget`` worlds × 8 episodes each, in one store: the atlas (CMA-ME over a 10×10 grid of
total curvature × sharpest corner), CMA-ES (population 21) and random search. Every campaign's
evaluations are then placed on the atlas's grid (``experiments.atlas_summary``) for:

- coverage: the share of the grid's cells holding at least one evaluated world;
- QD-score: Σ over filled cells of (worst return among all three campaigns − the cell's lowest
  return), so higher means lower returns in more kinds of worlds;
- failing worlds (``--failure``, default the paper's ``crash_rate > 0.5``) and how many of them
  are distinct tracks after repair.

Writes ``benchmarks/results/atlas-comparison.json`` with per-seed values and the machine.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: machine and the scripts imported
from machine import RESULTS, describe_machine  # noqa: E402
from worldagent import experiments  # noqa: E402
from worldagent.files import write_text  # noqa: E402
from worldagent.search.atlas import describer  # noqa: E402
from worldagent.store import RunStore  # noqa: E402

METHODS = ("atlas", "cmaes", "random")


def one_seed(store: RunStore, setup, budget: int, seed: int, failure: str) -> dict:
    """The three campaigns of ``seed`` and their figures on the atlas's grid."""
    clock = {}
    start = time.perf_counter()
    atlas = experiments.atlas(store, setup, "reward", maximize=False, budget=budget, seed=seed, failure=failure, progress=False)
    clock["atlas"] = time.perf_counter() - start
    names = {"atlas": atlas["evaluations"][0].campaign}
    for optimiser in ("cmaes", "random"):
        start = time.perf_counter()
        found, spec = experiments.search(
            store, setup, "reward", maximize=False, optimiser=optimiser, budget=budget, seed=seed, resume=True, progress=False
        )
        clock[optimiser] = time.perf_counter() - start
        names[optimiser] = spec.name
    grid = atlas["grid"]
    describe = describer(setup.spec, setup.generator, grid.descriptors)
    selection = experiments.failure_selection(failure, setup.spec.name)
    summary = experiments.atlas_summary(store, grid, describe, list(names.values()), False, selection)
    rows = {}
    for method, name in names.items():
        entry = summary[name]
        scores = np.array([e.score for e in entry["evaluations"][:budget]])
        rows[method] = {
            "campaign": name,
            "worlds": len(entry["evaluations"]),
            "coverage": round(entry["coverage"], 4),
            "qd_score": round(entry["qd_score"], 1),
            "failing_worlds": entry["failing"],
            "distinct_failing_worlds": entry["distinct_failing"],
            "lowest_return": round(float(np.nanmin(scores)), 2),
            "seconds": round(clock[method], 1),
        }
    return {"grid": grid.record(), "qd_offset": round(summary[names["atlas"]]["qd_offset"], 2), "methods": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, required=True, help="a `worldagent reproduce` run directory (its racing agent and generator)")
    parser.add_argument("--budget", type=int, default=2100)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--failure", default="crash_rate > 0.5")
    parser.add_argument("--work", type=Path, default=Path("runs/atlas-comparison"))
    args = parser.parse_args()
    setup = experiments.setup("racing", str(args.run / "racing" / "agent"), args.run / "racing" / "generator", repeats=8)
    per_seed = {}
    with RunStore(args.work) as store:
        for seed in args.seeds:
            per_seed[str(seed)] = one_seed(store, setup, args.budget, seed, args.failure)
            print(seed, json.dumps(per_seed[str(seed)]["methods"]))
    means = {
        method: {
            key: round(float(np.mean([per_seed[s]["methods"][method][key] for s in per_seed])), 3)
            for key in ("coverage", "qd_score", "failing_worlds", "distinct_failing_worlds")
        }
        for method in METHODS
    }
    result = {
        "benchmark": "atlas-comparison",
        "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "machine": describe_machine(),
        "command": "python benchmarks/studies/atlas_comparison.py " + " ".join(sys.argv[1:]),
        "agent": str(args.run / "racing" / "agent"),
        "generator": str(args.run / "racing" / "generator"),
        "budget": args.budget,
        "repeats": 8,
        "failure": args.failure,
        "per_seed": per_seed,
        "means": means,
    }
    path = write_text(RESULTS / "atlas-comparison.json", json.dumps(result, indent=2) + "\n")
    print(json.dumps(means, indent=1), "->", path)


if __name__ == "__main__":
    main()
