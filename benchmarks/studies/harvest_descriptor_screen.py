"""Which harvest descriptors let the surrogate proposal find low sustainability (issue 15, item 2).

    python benchmarks/studies/harvest_descriptor_screen.py [--worlds 100000] [--pilots 8]

On ``failure_rate.py``'s harvest generator, agent and brute force (its cache, ``--cache``), with
each map's one brute-force episode frozen:

1. every candidate descriptor of the decoded maps, and its correlation with sustainability;
2. for each candidate added to wall share and apple clustering, and for the spec's own
   descriptors, the surrogate fitted on ``--pilots`` pilots of 500 maps. Its pool shares q give
   the weights' relative variance v = Σ p²·1[event]/q / P² − 1 over the maps, so importance
   sampling needs ~ v (1.96 / 0.5)² episodes for ±50%, plus the pilot. The ratio divides Monte
   Carlo's episodes for ±50% by that.

Frozen episodes overstate what a proposal can do where the event is partly luck; the
recorded run with fresh episodes is ``failure_rate.py``'s. Writes
``benchmarks/results/harvest-descriptor-screen.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np
from scipy.ndimage import label

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: machine and the scripts imported
import failure_rate as bench  # noqa: E402
from machine import RESULTS, describe_machine  # noqa: E402
from worldagent import experiments  # noqa: E402
from worldagent.analysis import surrogate  # noqa: E402
from worldagent.envs.harvest.env import DISC_OFFSETS, perolat_regrowth_table  # noqa: E402
from worldagent.envs.harvest.world import HarvestMap, spawn_corners  # noqa: E402
from worldagent.files import write_text  # noqa: E402
from worldagent.search.objectives import generate  # noqa: E402

PILOT, PROBABILITIES = 500, (1e-3, 1e-4)


def walks_from_spawns(walls: np.ndarray) -> np.ndarray:
    """int[n, 4, H, W]: 4-move walks from each spawn around the walls of maps bool[n, H, W] (H + W where none reaches)."""
    n, height, width = walls.shape
    out = []
    for row, col in spawn_corners(height, width):
        reached = np.zeros_like(walls)
        reached[:, row, col] = ~walls[:, row, col]
        distance, step = np.where(reached, 0, height + width), 0
        while True:
            padded = np.pad(reached, ((0, 0), (1, 1), (1, 1)))
            grown = (padded[:, :-2, 1:-1] | padded[:, 2:, 1:-1] | padded[:, 1:-1, :-2] | padded[:, 1:-1, 2:] | reached) & ~walls
            if (grown == reached).all():
                break
            step += 1
            distance, reached = np.where(grown & ~reached, step, distance), grown
        out.append(distance)
    return np.stack(out, 1)


def candidates(walls: np.ndarray, apples: np.ndarray) -> dict[str, np.ndarray]:
    """f64[n] per candidate descriptor of maps bool[n, H, W]."""
    n, height, width = walls.shape
    walks = walks_from_spawns(walls)
    nearest = np.where(apples[:, None], walks, height + width).min(axis=(2, 3))  # [n, 4] each spawn's walk to an apple
    to_spawn = walks.min(axis=1)
    padded = np.pad(apples, ((0, 0), (2, 2), (2, 2))).astype(np.int32)
    disc = sum(padded[:, 2 + dr : 2 + dr + height, 2 + dc : 2 + dc + width] for dr, dc in DISC_OFFSETS)
    count = apples.sum(axis=(1, 2))
    patches = [label(a, structure=np.ones((3, 3))) for a in apples]
    return {
        "apple count": count.astype(float),
        "walk from the spawns to the nearest apple (apple_distance)": nearest.mean(axis=1),
        "the longest of those 4 walks": nearest.max(axis=1),
        "the shortest of those 4 walks": nearest.min(axis=1),
        "largest 8-connected apple patch (largest_patch)": np.array([np.bincount(p.ravel())[1:].max() if k else 0 for p, k in patches], float),
        "apple patches": np.array([k for _, k in patches], float),
        "apples within 5 steps of a spawn": (apples & (to_spawn <= 5)).sum(axis=(1, 2)).astype(float),
        "mean walk from the apples to their nearest spawn": np.where(apples, to_spawn, 0).sum(axis=(1, 2)) / np.maximum(count, 1),
        "regrowth rate of the full map": (perolat_regrowth_table()[disc] * apples).sum(axis=(1, 2)).astype(float),
        "isolated apples (none within 2 cells)": (apples & (disc == 0)).sum(axis=(1, 2)).astype(float),
    }


def ratio(x: np.ndarray, values: np.ndarray, p: float, pilots: int) -> tuple[float, float]:
    """(median, worst) over the pilots of Monte Carlo's episodes for ±50% over the surrogate's (pilot included)."""
    threshold = bench.threshold_for(values, p, "<")
    event = values < threshold
    truth, mc = event.mean(), bench.mc_worlds_for_width(event.mean(), 0.5)
    found = []
    for seed in range(pilots):
        pilot = np.random.default_rng(seed).choice(len(values), PILOT, replace=False)
        q = surrogate.pool_shares(surrogate.log_chances(x, x[pilot], threshold - values[pilot]), 0.1)
        variance = np.sum(event / q) / len(values) ** 2 / truth**2 - 1
        found.append(mc / (variance * (1.96 / 0.5) ** 2 + PILOT))
    return round(float(np.median(found)), 1), round(float(np.min(found)), 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=100_000, help="brute-force maps (failure_rate.py's cache for this count)")
    parser.add_argument("--pilots", type=int, default=8)
    parser.add_argument("--cache", type=Path, default=Path("runs/frcache"))
    args = parser.parse_args()
    start, settings = time.perf_counter(), bench.ENVS["harvest"]
    setup = experiments.setup("harvest", settings["agent"], bench.small_generator("harvest", settings["dataset"], settings["epochs"]), repeats=1)
    means, dim = bench.metric_means(setup, settings["metric"]), setup.generator.latent_dim
    values, _ = bench.brute_force(means, dim, args.worlds, 0, args.cache, f"harvest-{bench.generator_hash(setup.generator)}")
    z = np.concatenate([z for z, _ in bench.brute_force_draws(dim, args.worlds, 0)])
    maps = [generate(setup.generator, jnp.asarray(z[i : i + bench.CHUNK], jnp.float32)) for i in range(0, len(z), bench.CHUNK)]
    walls, apples = (np.concatenate([np.asarray(getattr(m, name), bool) for m in maps]) for name in ("walls", "apples"))
    found = candidates(walls, apples)
    spec = setup.spec.metrics.descriptors
    own = {name: np.array([f(HarvestMap(w, a)) for w, a in zip(walls, apples, strict=True)]) for name, f in spec.items()}
    base = [own["wall_share"], own["apple_clustering"]]
    rows = []
    for name, column in {"none (wall share and clustering only)": None, **found}.items():
        x = surrogate.features(z, np.stack(base + ([] if column is None else [column]), axis=1))
        spread = column is not None and column.std() > 0
        row = {"added": name, "corr": round(float(np.corrcoef(column, values)[0, 1]), 3) if spread else None}
        rows.append(row | {f"{p:g}": ratio(x, values, p, args.pilots) for p in PROBABILITIES})
        print(rows[-1], flush=True)
    x = surrogate.features(z, np.stack(list(own.values()), axis=1))
    kept = {"descriptors": list(own), **{f"{p:g}": ratio(x, values, p, args.pilots) for p in PROBABILITIES}}
    print("spec's descriptors:", kept, flush=True)
    payload = {"benchmark": "harvest_descriptor_screen", "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "machine": describe_machine()}
    payload |= {"settings": vars(args) | {"cache": str(args.cache), "pilot": PILOT}, "candidates": rows, "spec_descriptors": kept}
    payload["seconds"] = round(time.perf_counter() - start, 1)
    print("->", write_text(RESULTS / "harvest-descriptor-screen.json", json.dumps(payload, indent=2) + "\n"), flush=True)


if __name__ == "__main__":
    main()
