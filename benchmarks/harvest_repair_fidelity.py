"""Harvest maps as G(z) makes them against fresh maps of the generator (issue 48 item 3).

    cp -r runs/quick/harvest/generator /tmp/harvest-gen
    python benchmarks/harvest_repair_fidelity.py --generator /tmp/harvest-gen [--decodes 1000] [--result FILE]

``--decodes`` latents z ~ N(0, I) (key 0), decoded once and repaired by each repair, each fitted to
the decoder as a new generator's is (``worlds.generator.fit_repair``): ``open`` (``OpenRooms``'
defaults: wall and entrance shifts fitted, apples spread, entrances by the tempered rule),
``open_unshifted`` (what open generators saved with "spread" before the wall and entrance fits
record: no wall or entrance shift), ``open_clusters`` (what open generators saved from issue 48
until "spread" record: clusters without spacing or shift), ``open_top_k`` (what open generators
saved before issue 48 record: exactly K apples on the top-K cells, entrances by the posterior
rule), ``nearest`` (the dataset layout the wall logits score highest, apples spread in the
layout's rooms). Against as many
fresh maps of the procedural generator at seeds past the dataset's largest (``worlds.coverage.fresh_worlds``),
and a second fresh range beside them (``fresh_again``: what a perfect generator scores at this size).

Per side: apple count (mean, 5/25/50/75/95 % quantiles); clusters as 8-connected apple patches
(count per map, sizes); apple positions (each cell's share of maps with an apple there, its
correlation with fresh maps'); rooms per map (``apples.rooms_from_walls`` on every side's walls);
closed-room rate (some free cell unreachable from another,
4-moves) against fresh maps' and the dataset's; the spawns' walk to the nearest apple (the env's
``apple_distance`` descriptor); wall novelty (share of layouts in no dataset map)
and the median Hamming distance of the novel ones to their nearest dataset layout; warm
milliseconds per world of each repair (one jitted call on all decodes). Each statistic's relative
difference to fresh maps' is recorded beside it. Written to benchmarks/results/harvest-repair-fidelity.json
(``--result``: another file, e.g. for a second VAE).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parent))
from harvest_open_repair import warm_ms  # noqa: E402  (warm ms per map of a jitted repair)
from machine import describe_machine, require_input  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.envs.harvest.apples import rooms_from_walls  # noqa: E402
from worldagent.envs.harvest.open_repair import OpenRooms  # noqa: E402
from worldagent.envs.harvest.repair import HarvestRepair, median_apples, wall_layouts  # noqa: E402
from worldagent.envs.harvest.spec import apple_distance  # noqa: E402
from worldagent.envs.harvest.world import HarvestMap  # noqa: E402
from worldagent.files import write_text  # noqa: E402
from worldagent.worlds.coverage import fresh_worlds  # noqa: E402
from worldagent.worlds.generator import build_generator, fit_repair, load_generator  # noqa: E402

RESULT = Path(__file__).resolve().parent / "results" / "harvest-repair-fidelity.json"
QUANTILES = (5, 25, 50, 75, 95)
FOUR = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]])
EIGHT = np.ones((3, 3), int)


def spread(values) -> dict:
    values = np.asarray(values, np.float64)
    return {"mean": float(values.mean()), "quantiles": np.percentile(values, QUANTILES).tolist()}


def nearest_distances(walls: np.ndarray, layouts: np.ndarray) -> np.ndarray:
    """int[B]: each wall grid's Hamming distance to its nearest dataset layout f32[L, H·W]."""
    flat = jnp.asarray(walls.reshape(len(walls), -1), jnp.float32)
    known = jnp.asarray(layouts)
    # |a - b| summed = |a| + |b| - 2 a·b for 0/1 vectors
    distance = flat.sum(1)[:, None] + known.sum(1)[None, :] - 2.0 * flat @ known.T
    return np.asarray(jnp.round(distance.min(axis=1))).astype(int)


def describe(walls: np.ndarray, apples: np.ndarray, layouts: np.ndarray, rooms: np.ndarray) -> dict:
    """The statistics of one side's maps (see the module doc)."""
    patches = [ndimage.label(a, EIGHT) for a in apples]
    sizes = np.concatenate([np.bincount(labels.ravel())[1:] for labels, _ in patches])
    known = {row.astype(bool).tobytes() for row in layouts}
    novel = np.array([w.reshape(-1).tobytes() not in known for w in walls])
    distance = nearest_distances(walls, layouts)
    return {
        "apple_count": spread(apples.sum(axis=(1, 2))),
        "clusters_per_map": spread([count for _, count in patches]),
        "cluster_size": spread(sizes),
        "rooms_per_map": float(rooms.any(axis=(2, 3)).sum(axis=1).mean()),
        "closed_room": float(np.mean([ndimage.label(~w, FOUR)[1] > 1 for w in walls])),
        "apple_distance": spread([apple_distance(HarvestMap(walls=w, apples=a)) for w, a in zip(walls, apples)]),
        "novel_layouts": float(novel.mean()),
        "novel_median_distance": float(np.median(distance[novel])) if novel.any() else None,
        "occupancy": apples.mean(axis=0),
    }


def relative(side: dict, fresh: dict) -> dict:
    """Each scalar statistic's (side - fresh) / fresh."""
    out = {}
    for key in ("apple_count", "clusters_per_map", "cluster_size", "apple_distance"):
        out[f"{key}_mean"] = side[key]["mean"] / fresh[key]["mean"] - 1
        out[f"{key}_median"] = side[key]["quantiles"][2] / fresh[key]["quantiles"][2] - 1
    for key in ("rooms_per_map", "closed_room"):
        out[key] = side[key] / fresh[key] - 1
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--generator", type=Path, required=True, help="a harvest generator directory (a copy: nothing is written there)")
    parser.add_argument("--decodes", type=int, default=1000)
    parser.add_argument("--result", type=Path, default=RESULT, help="where to write (default: %(default)s)")
    args = parser.parse_args()
    started = time.perf_counter()
    require_input(args.generator / "generator.json", "worldagent generator train harvest --out DIR")
    generator, vae, dataset = load_generator(args.generator)
    spec = registry.get("harvest")
    unshifted = {"wall_shift": 0.0, "entrance_shift": 0.0}  # what generators saved before the wall and entrance fits record
    unfitted = {
        "open": OpenRooms.from_dataset(dataset),
        "open_unshifted": OpenRooms.from_dataset(dataset, unshifted),
        "open_clusters": OpenRooms.from_dataset(dataset, {"apples": "clusters", **unshifted}),
        "open_top_k": OpenRooms.from_dataset(dataset, {"apples": median_apples(dataset.worlds), "entrances": "posterior", **unshifted}),
        "nearest": HarvestRepair.from_dataset(dataset, {"apples": "spread"}),
    }
    repairs = {name: fit_repair(build_generator(vae, dataset, repair=repair), dataset).repair for name, repair in unfitted.items()}
    z = jax.random.normal(jax.random.key(0), (args.decodes, generator.latent_dim))
    logits = jnp.asarray(generator.logits(z))
    layouts = wall_layouts(dataset.worlds)
    fresh = fresh_worlds(spec, dataset, args.decodes).worlds
    again = fresh_worlds(spec, dataset, args.decodes, offset=args.decodes).worlds
    room_finder = jax.jit(jax.vmap(rooms_from_walls))
    sides, cost = {}, {}
    for name, worlds in (("fresh", fresh), ("fresh_again", again)):
        walls, apples = np.asarray(worlds.walls, bool), np.asarray(worlds.apples, bool)
        sides[name] = describe(walls, apples, layouts, np.asarray(room_finder(jnp.asarray(walls))))
    for name, repair in repairs.items():
        maps = jax.jit(lambda x, r=repair: r(x))(logits)
        walls, apples = np.asarray(maps.walls, bool), np.asarray(maps.apples, bool)
        assert not (walls & apples).any()
        sides[name] = describe(walls, apples, layouts, np.asarray(room_finder(jnp.asarray(walls))))
        cost[name] = round(warm_ms(repair, logits), 3)
        print(f"{name}: {cost[name]} ms/world", flush=True)
    dataset_walls = np.asarray(dataset.worlds.walls, bool)
    reference = sides["fresh"]
    for name, side in sides.items():
        side["occupancy_correlation_with_fresh"] = float(np.corrcoef(side["occupancy"].ravel(), reference["occupancy"].ravel())[0, 1])
        if name != "fresh":
            side["relative_to_fresh"] = relative(side, reference)
    result = {
        "benchmark": "harvest_repair_fidelity",
        "command": f"python benchmarks/harvest_repair_fidelity.py --generator {args.generator} --decodes {args.decodes}"
        + ("" if args.result == RESULT else f" --result {args.result}"),
        "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "machine": describe_machine(),
        "generator": str(args.generator),
        "decodes": args.decodes,
        "repair_configs": {name: repair.config for name, repair in repairs.items()},
        "dataset": {
            "maps": len(dataset_walls),
            "distinct_layouts": len(layouts),
            "closed_room": float(np.mean([ndimage.label(~w, FOUR)[1] > 1 for w in dataset_walls])),
            "apple_count": spread(np.asarray(dataset.worlds.apples).sum(axis=(1, 2))),
        },
        "sides": {name: {key: value for key, value in side.items() if key != "occupancy"} for name, side in sides.items()},
        "ms_per_world": cost,
        "wall_seconds": round(time.perf_counter() - started, 1),
    }
    write_text(args.result, json.dumps(result, indent=2) + "\n")
    for name, side in result["sides"].items():
        print(name, json.dumps({k: v for k, v in side.items()}))
    print(f"recorded in {args.result}")


if __name__ == "__main__":
    main()
