"""Harvest's open repair against the nearest one, on a trained generator's decodes.

    worldagent generator train harvest --out runs/harvest-gen --n 5000 --epochs 100
    python benchmarks/harvest_open_repair.py --generator runs/harvest-gen [--decodes 1000] [--seeds 0 1 2]

Per repair (``nearest``: the dataset layout the wall logits score highest; ``open``:
``OpenRooms``, the generator layout they score highest; ``open_likelihood_entrances``: the same
with ``entrances="likelihood"``), on ``--decodes`` latents z ~ N(0, I) per
seed: the share of valid maps (``HarvestMap.validate`` and exactly K apples), the share with a
closed room (some free cell unreachable from another, 4-moves), against the dataset's share; the
share of wall layouts not in the dataset; distinct layouts; the mean wall log-likelihood
``Σ W·l`` (up to a constant) and how often it is at least nearest's (open with likelihood entrances
maximises it: this checks the search); warm milliseconds per map.
Also the share of freshly generated maps whose own cells, as ±8 logits, repair back to their
walls. Recorded with ``machine.record("harvest_open_repair", ...)``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import record  # noqa: E402
from worldagent.envs.harvest.maps import generate_maps, seeds_from  # noqa: E402
from worldagent.envs.harvest.open_repair import OpenRooms  # noqa: E402
from worldagent.envs.harvest.repair import HarvestRepair, wall_layouts  # noqa: E402
from worldagent.envs.harvest.spec import cells, tagger_separated  # noqa: E402
from worldagent.envs.harvest.world import index_maps  # noqa: E402
from worldagent.errors import WorldagentError  # noqa: E402
from worldagent.worlds.generator import build_generator, load_generator  # noqa: E402

FOUR_NEIGHBOURS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]])


def closed_room(walls: np.ndarray) -> bool:
    """Whether some free cell of a map bool[H, W] is unreachable from another (a closed room)."""
    return ndimage.label(~walls, FOUR_NEIGHBOURS)[1] > 1


def valid(maps, apples: int) -> np.ndarray:
    """bool[B]: each map passes ``validate`` and holds exactly ``apples`` apples."""
    ok = []
    for i in range(len(maps.walls)):
        try:
            index_maps(maps, i).validate()
            ok.append(int(np.asarray(maps.apples[i]).sum()) == apples)
        except WorldagentError:
            ok.append(False)
    return np.asarray(ok)


def warm_ms(repair, logits) -> float:
    """Warm milliseconds per map of one jitted call of ``repair`` on ``logits``."""
    run = jax.jit(lambda x: repair(x))
    jax.block_until_ready(run(logits))
    start = time.perf_counter()
    jax.block_until_ready(run(logits))
    return 1e3 * (time.perf_counter() - start) / len(logits)


def describe(maps, wall_logit: np.ndarray, known: set, apples: int) -> dict:
    """The measures of one repair's maps (see the module doc)."""
    walls = np.asarray(maps.walls, bool)
    keys = [w.reshape(-1).tobytes() for w in walls]
    return {
        "valid": float(valid(maps, apples).mean()),
        "closed_room": float(np.mean([closed_room(w) for w in walls])),
        "tagger_separated": float(np.mean([tagger_separated(index_maps(maps, i)) for i in range(len(walls))])),
        "novel_layouts": float(np.mean([key not in known for key in keys])),
        "distinct_layouts": len(set(keys)),
        "log_likelihood": (walls.reshape(len(walls), -1) * wall_logit.reshape(len(walls), -1)).sum(axis=1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--generator",
        type=Path,
        required=True,
        help="a trained harvest generator directory (make one: worldagent generator train harvest --out DIR --n 5000 --epochs 100)",
    )
    parser.add_argument("--decodes", type=int, default=1000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--recover", type=int, default=1000, help="generated maps for the recovery check")
    args = parser.parse_args()
    _, vae, dataset = load_generator(args.generator)
    open_repair = OpenRooms.from_dataset(dataset)
    repairs = {
        "nearest": HarvestRepair.from_dataset(dataset, {"apples": open_repair.apples}),
        "open": open_repair,
        "open_likelihood_entrances": OpenRooms.from_dataset(dataset, {"entrances": "likelihood"}),
    }
    generators = {name: build_generator(vae, dataset, repair=repair) for name, repair in repairs.items()}
    known = {row.astype(bool).tobytes() for row in wall_layouts(dataset.worlds)}
    reference = {
        "closed_room": float(np.mean([closed_room(w) for w in np.asarray(dataset.worlds.walls, bool)])),
        "tagger_separated": float(np.mean([tagger_separated(index_maps(dataset.worlds, i)) for i in range(len(dataset.cells))])),
        "distinct_layouts": len(known),
        "maps": len(dataset.cells),
    }
    per_seed = []
    for seed in args.seeds:
        z = jax.random.normal(jax.random.key(seed), (args.decodes, generators["open"].latent_dim))
        logits = np.asarray(generators["open"].logits(z))
        wall_logit = logits.reshape(len(logits), 2, -1)[:, 0]
        measured = {name: describe(generator(z), wall_logit, known, open_repair.apples) for name, generator in generators.items()}
        nearest = measured["nearest"]["log_likelihood"]
        for result in measured.values():
            result["at_least_nearest"] = float(np.mean(result["log_likelihood"] >= nearest - 1e-3))
            result["log_likelihood"] = float(result["log_likelihood"].mean())
        per_seed.append(measured)
        print(f"seed {seed}: {measured}", flush=True)
    fresh = generate_maps(seeds_from(10_000_000, args.recover))
    recovered = np.asarray(open_repair(8.0 * (2.0 * jnp.asarray(cells(fresh), jnp.float32) - 1.0)).walls)
    logits = jnp.asarray(generators["open"].logits(jax.random.normal(jax.random.key(99), (args.decodes, generators["open"].latent_dim))))
    result = {
        "generator": str(args.generator),
        "decodes": args.decodes,
        "seeds": args.seeds,
        "apples": open_repair.apples,
        "open_config": open_repair.config,
        "dataset": reference,
        "per_seed": per_seed,
        "mean": {name: {key: float(np.mean([seed[name][key] for seed in per_seed])) for key in per_seed[0][name]} for name in repairs},
        "recovered_own_walls": float((recovered == fresh.walls).all(axis=(1, 2)).mean()),
        "ms_per_map": {name: round(warm_ms(repair, logits), 3) for name, repair in repairs.items()},
    }
    print(f"dataset: {reference}")
    for name in repairs:
        print(f"{name}: {result['mean'][name]}")
    print(f"recovered own walls {result['recovered_own_walls']:.3f}")
    print(f"ms per map (warm, batch {args.decodes}): {result['ms_per_map']}")
    print(f"recorded in {record('harvest_open_repair', result)}")


if __name__ == "__main__":
    main()
