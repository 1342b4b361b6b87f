"""What z can reach: each repair of G(z) measured on the same VAE (issue 39, item 3).

    python benchmarks/open_worlds.py --generator racing=runs/open/racing/generator --generator harvest=runs/open/harvest/generator

For every environment given (a trained generator directory; its VAE is repaired both ways) and
every repair the environment names (``EnvSpec.repairs``: the paper's ``nearest`` and ``open``),
on ``--samples`` latents z ~ N(0, I):

- validity: the share of decoded worlds that pass ``validate()``;
- novelty: the share of decoded worlds whose cells equal no dataset world's, distinct worlds, and
  the distance to the nearest dataset world (the share of cells that differ);
- each descriptor's range under G(z) (min, 5 %, median, 95 %, max, std) against the dataset's;
- for each ``--push`` descriptor: CMA-ES over z (population 21, ``--budget`` decodes, ``--seeds``
  seeds) maximising it, against the dataset's maximum;
- decode cost: warm milliseconds per world of one jitted G(z) call of ``--samples`` latents.

``--repair NAME`` (repeatable) measures only those repairs. Recorded in
``benchmarks/results/<--record, default open-worlds>-<backend>.json`` with the machine; ``--figures DIR``
also draws, per environment, the first ``FIGURE_WORLDS`` open decodes above their nearest dataset
worlds (``DIR/open-worlds-<env>.png``, for docs/open-worlds.md).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cma
import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import record  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.errors import WorldagentError  # noqa: E402
from worldagent.worlds.generator import build_generator, load_generator  # noqa: E402

CHUNK = 500  # latents per jitted call
FIGURE_WORLDS = 6
FIGURE_SIZE = 160  # pixels per world
POPULATION = 21  # the paper's CMA-ES population (§5.2.2)
DATASET_DESCRIBED = 10_000  # dataset worlds whose descriptors are measured


def decode(generator, z: np.ndarray):
    """The worlds of latents z f[N, L], as one numpy batch."""
    g = jax.jit(lambda gen, zz: gen(zz))
    parts = [jax.tree_util.tree_map(np.asarray, g(generator, z[i : i + CHUNK])) for i in range(0, len(z), CHUNK)]
    return jax.tree_util.tree_map(lambda *leaves: np.concatenate(leaves), *parts)


def one(worlds, i: int):
    return jax.tree_util.tree_map(lambda leaf: leaf[i], worlds)


def valid(world) -> bool:
    try:
        world.validate()
    except WorldagentError:
        return False
    return True


def nearest_distance(cells: np.ndarray, dataset_cells: np.ndarray) -> np.ndarray:
    """f64[N]: the share of cells in which each world differs from its nearest dataset world."""
    a, b = cells.astype(np.float32), dataset_cells.astype(np.float32)
    b_ones = b.sum(1)
    out = np.empty(len(a))
    for i in range(0, len(a), 250):
        block = a[i : i + 250]
        hamming = block.sum(1)[:, None] + b_ones[None, :] - 2 * block @ b.T
        out[i : i + 250] = hamming.min(1) / a.shape[1]
    return out


def nearest_index(cells: np.ndarray, dataset_cells: np.ndarray) -> np.ndarray:
    """int[N]: the dataset world nearest (fewest differing cells) to each world."""
    a, b = cells.astype(np.float32), dataset_cells.astype(np.float32)
    return np.argmin(a.sum(1)[:, None] + b.sum(1)[None, :] - 2 * a @ b.T, axis=1)


def figure(spec, generator, dataset, path: Path) -> Path:
    """The first ``FIGURE_WORLDS`` decodes of z ~ N(0, I) (top row) above their nearest dataset worlds (bottom row)."""
    from PIL import Image, ImageDraw

    z = np.asarray(jax.random.normal(jax.random.key(0), (FIGURE_WORLDS, generator.latent_dim)))
    worlds = decode(generator, z)
    nearest = nearest_index(np.asarray(spec.cells(worlds), np.uint8), dataset.cells)
    caption = 18  # pixels above each row
    step = FIGURE_SIZE + 6  # a white gutter between worlds
    sheet = Image.new("RGB", (FIGURE_WORLDS * step, 2 * (FIGURE_SIZE + caption)), "white")
    draw = ImageDraw.Draw(sheet)
    draw.text((4, 3), f"G(z), z ~ N(0, I), {generator.repair_name} repair", fill="black")
    draw.text((4, FIGURE_SIZE + caption + 3), "the nearest dataset world (fewest differing cells)", fill="black")
    for i in range(FIGURE_WORLDS):
        sheet.paste(spec.pictures.world(one(worlds, i), FIGURE_SIZE).convert("RGB"), (i * step, caption))
        below = spec.pictures.world(dataset.world(int(nearest[i])), FIGURE_SIZE).convert("RGB")
        sheet.paste(below, (i * step, FIGURE_SIZE + 2 * caption))
    path.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(path)
    return path


def spread(values: np.ndarray) -> dict:
    q = np.percentile(values, [0, 5, 50, 95, 100])
    return {"min": q[0], "p5": q[1], "median": q[2], "p95": q[3], "max": q[4], "std": float(values.std()), "mean": float(values.mean())}


def describe(spec, worlds, count: int) -> dict[str, np.ndarray]:
    return {name: np.array([fn(one(worlds, i)) for i in range(count)]) for name, fn in spec.metrics.descriptors.items()}


def push(generator, describe_one, budget: int, seed: int) -> float:
    """The highest value of a descriptor CMA-ES finds over z in ``budget`` decodes (maximising)."""
    strategy = cma.CMAEvolutionStrategy(np.zeros(generator.latent_dim), 1.0, {"popsize": POPULATION, "seed": seed + 1, "verbose": -9})
    best = -np.inf
    for _ in range(max(1, budget // POPULATION)):
        z = np.asarray(strategy.ask())
        worlds = decode(generator, z)
        values = np.array([describe_one(one(worlds, i)) for i in range(len(z))])
        strategy.tell(list(z), list(-values))
        best = max(best, float(values.max()))
    return best


def measure(generator, dataset, spec, samples: int, pushes: list[str], budget: int, seeds: list[int], reference: dict) -> dict:
    """The figures of one repair (see the module docstring)."""
    z = np.asarray(jax.random.normal(jax.random.key(0), (samples, generator.latent_dim)))
    decode(generator, z[:CHUNK])  # compile
    start = time.perf_counter()
    worlds = decode(generator, z)
    milliseconds = 1e3 * (time.perf_counter() - start) / samples
    cells = np.asarray(spec.cells(worlds), np.uint8)
    known = {row.tobytes() for row in dataset.cells}
    described = describe(spec, worlds, samples)
    out = {
        "repair": generator.repair_name,
        "repair_config": dict(generator.repair.config),
        "validity": float(np.mean([valid(one(worlds, i)) for i in range(samples)])),
        "new_share": float(np.mean([row.tobytes() not in known for row in cells])),
        "distinct": len({row.tobytes() for row in cells}),
        "nearest_dataset_distance": spread(nearest_distance(cells, dataset.cells)),
        "descriptors": {name: spread(values) for name, values in described.items()},
        "decode_ms_per_world": milliseconds,
        "push": {},
    }
    for name in pushes:
        best = [push(generator, spec.metrics.descriptors[name], budget, seed) for seed in seeds]
        out["push"][name] = {
            "best_per_seed": best,
            "dataset_max": reference[name]["max"],
            "beyond_dataset_max": [bool(b > reference[name]["max"]) for b in best],
        }
        print(f"  {generator.repair_name}: push {name}: {np.round(best, 3)} vs dataset max {reference[name]['max']:.3f}", flush=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--generator", action="append", required=True, help="ENV=DIR: a trained generator of ENV (repeatable).")
    parser.add_argument("--samples", type=int, default=1000)
    parser.add_argument("--budget", type=int, default=420, help="Decodes per CMA-ES push.")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--push", action="append", default=[], help="ENV=DESCRIPTOR to push past the dataset's maximum (repeatable).")
    parser.add_argument("--figures", type=Path, default=None, help="draw open decodes beside their nearest dataset worlds here")
    parser.add_argument("--repair", action="append", default=None, help="measure only this repair (repeatable; default: every one the env names)")
    parser.add_argument("--record", default="open-worlds", help="results file name, before -<backend>.json (another name keeps the full study)")
    args = parser.parse_args()
    pushes: dict[str, list[str]] = {}
    for text in args.push:
        env, _, name = text.partition("=")
        pushes.setdefault(env, []).append(name)
    result = {"samples": args.samples, "budget": args.budget, "seeds": args.seeds, "envs": {}}
    for text in args.generator:
        env, _, directory = text.partition("=")
        _, vae, dataset = load_generator(directory)
        spec = registry.get(env)
        count = min(len(dataset), DATASET_DESCRIBED)
        reference = {name: spread(values) for name, values in describe(spec, dataset.worlds, count).items()}
        entry = {
            "generator": directory,
            "vae_epochs": len(vae.history),
            "dataset_worlds": len(dataset),
            "dataset_descriptors": reference,
            "repairs": {},
        }
        for name in [name for name in spec.repair_names if args.repair is None or name in args.repair]:
            print(f"{env}: {name}", flush=True)
            generator = build_generator(vae, dataset, repair_name=name)
            entry["repairs"][name] = measure(generator, dataset, spec, args.samples, pushes.get(env, []), args.budget, args.seeds, reference)
            if args.figures is not None and name != spec.default_repair:
                entry["repairs"][name]["figure"] = str(figure(spec, generator, dataset, args.figures / f"open-worlds-{env}-{name}.png"))
            shown = {k: entry["repairs"][name][k] for k in ("validity", "new_share", "distinct", "decode_ms_per_world")}
            print(f"  {shown}", flush=True)
        result["envs"][env] = entry
    print(f"recorded in {record(args.record, result)}")


if __name__ == "__main__":
    main()
