"""How far CMA-ES pushes a descriptor inside the prior's typical set, and beyond it (issue 48, item 4).

    python benchmarks/prior_extremes.py [--generator runs/quick/racing/generator] [--budget 420] [--seeds 0 1 2]

For each repair of G(z) (``--repair``, default ``open`` and ``nearest``, both on the generator directory's VAE) and each
``--descriptor`` (default racing's ``sharpest_corner`` and ``total_curvature``), CMA-ES (the campaigns' own: population
21, sigma 1, ``search.campaign.run_campaign`` on a throwaway store) maximises the descriptor of G(z) for ``--budget``
decodes, per seed, under three bounds:

- ``typical``: the default of every search, |z| <= the prior's 99.9% radius (``search.prior.typical_radius``: 5.44 in
  10 dimensions), latents projected onto that ball before they are decoded;
- ``none``: what ``--prior-bound none`` searches, the optimiser's own box |z_i| <= 3 (|z| up to 9.5);
- ``unbounded``: no bound and no box, as ``benchmarks/open_worlds.py --push`` measured (|z| = 41.8 passed the
  dataset's maximum there).

Recorded per run: the best value at ``--budget`` and at half of it (the same run: a campaign's first half is the half
budget's run), its latent's |z|, the percentile of that |z| under the prior and its log10 tail. Against: the dataset's
maximum (up to 10,000 of its worlds), fresh tracks of the env's own generator at unused seeds (``--fresh``: 95th and 99th
percentiles and maximum), and G(z) on ``--fresh`` prior draws (the same quantiles). Written to
``benchmarks/results/prior-extremes.json`` with the command, the machine and the wall time.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import QUICK_RUN, RESULTS, describe_machine, require_input  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.files import write_text  # noqa: E402
from worldagent.search.campaign import CampaignSpec, Outcome, run_campaign  # noqa: E402
from worldagent.search.objectives import generate  # noqa: E402
from worldagent.search.optimisers import OptimiserConfig  # noqa: E402
from worldagent.search.prior import latent_norm, norm_percentile, norm_tail_log10, typical_radius  # noqa: E402
from worldagent.store import RunStore  # noqa: E402
from worldagent.worlds.coverage import fresh_worlds  # noqa: E402
from worldagent.worlds.generator import build_generator, load_generator  # noqa: E402

# bound name -> (CampaignSpec.prior_bound, the optimiser's box): see the module docstring
BOUNDS = {"typical": ("typical", OptimiserConfig().bound), "none": (None, OptimiserConfig().bound), "unbounded": (None, 0.0)}
DATASET_DESCRIBED = 10_000
CHUNK = 256  # latents decoded per call when describing prior draws


def world(worlds, i: int):
    return jax.tree_util.tree_map(lambda leaf: np.asarray(leaf[i]), worlds)


class DescriptorObjective:
    """``evaluate(z[n, dim], seeds[n]) -> [Outcome]`` for ``run_campaign``: a descriptor of G(z), decoded as a campaign decodes."""

    def __init__(self, generator, function):
        self.generator, self.function = generator, function

    def __call__(self, z, seeds):
        worlds = jax.tree_util.tree_map(np.asarray, generate(self.generator, z))
        values = [float(self.function(world(worlds, i))) for i in range(len(z))]
        return [Outcome(v, [{"value": v}]) for v in values]


def quantiles(values: np.ndarray) -> dict:
    return {"p95": float(np.percentile(values, 95)), "p99": float(np.percentile(values, 99)), "max": float(values.max()), "n": int(len(values))}


def describe_all(spec, worlds, count: int, names) -> dict[str, np.ndarray]:
    return {name: np.array([spec.metrics.descriptors[name](world(worlds, i)) for i in range(count)]) for name in names}


def prior_draws(generator, spec, count: int, names) -> dict[str, np.ndarray]:
    """Each descriptor of G(z) on ``count`` prior draws (key 0)."""
    z = np.asarray(jax.random.normal(jax.random.key(0), (count, generator.latent_dim)))
    parts = [
        describe_all(spec, jax.tree_util.tree_map(np.asarray, generate(generator, z[i : i + CHUNK])), len(z[i : i + CHUNK]), names)
        for i in range(0, count, CHUNK)
    ]
    return {name: np.concatenate([p[name] for p in parts]) for name in names}


def where(latent: np.ndarray) -> dict:
    norm, dim = float(latent_norm(latent)), latent.size
    return {"norm": norm, "percentile": float(norm_percentile(norm, dim)), "tail_log10": float(norm_tail_log10(norm, dim))}


def push(generator, function, descriptor: str, bound: str, budget: int, seed: int) -> dict:
    """One CMA-ES campaign maximising ``descriptor``; its best value (and latent) at half the budget and at the budget."""
    prior_bound, box = BOUNDS[bound]
    spec = CampaignSpec(
        "push", generator.env, descriptor, True, "cmaes", budget, seed, generator.latent_dim, OptimiserConfig(bound=box), prior_bound=prior_bound
    )
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as folder, RunStore(Path(folder)) as store:
        found = run_campaign(store, spec, DescriptorObjective(generator, function), progress=False)
    latents, scores = np.stack([e.latent for e in found]), np.array([e.score for e in found])
    out = {"seconds": time.perf_counter() - started, "max_norm_evaluated": float(latent_norm(latents).max())}
    for label, count in (("half", budget // 2), ("full", len(found))):
        best = int(np.argmax(scores[:count]))
        out[label] = {"evaluations": count, "value": float(scores[best]), **where(latents[best])}
    return out


def commit() -> str | None:
    """The checkout's commit (the repairs measured are its), or None outside a git checkout."""
    import subprocess

    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True, cwd=Path(__file__).parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--generator", type=Path, default=Path("runs/quick/racing/generator"), help="A trained generator directory.")
    parser.add_argument("--repair", action="append", default=None, help="Repairs to push (repeatable; default open and nearest).")
    parser.add_argument(
        "--descriptor", action="append", default=None, help="Descriptors to maximise (repeatable; default sharpest_corner, total_curvature)."
    )
    parser.add_argument("--bound", action="append", default=None, choices=sorted(BOUNDS), help="Bounds (repeatable; default all three).")
    parser.add_argument("--budget", type=int, default=420, help="Decodes per CMA-ES run (the half budget is read from the same run).")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--fresh", type=int, default=2000, help="Fresh procedural worlds, and prior draws of G(z), for the percentiles.")
    args = parser.parse_args()
    started = time.perf_counter()
    nearest, vae, dataset = load_generator(require_input(args.generator, QUICK_RUN))
    spec = registry.get(nearest.env)
    names = args.descriptor or ["sharpest_corner", "total_curvature"]
    repairs = args.repair or ["open", "nearest"]
    bounds = args.bound or list(BOUNDS)
    count = min(len(dataset), DATASET_DESCRIBED)
    data = describe_all(spec, dataset.worlds, count, names)
    fresh = fresh_worlds(spec, dataset, args.fresh)
    fresh_values = describe_all(spec, fresh.worlds, len(fresh), names)
    result = {
        "command": "python " + " ".join(sys.argv),
        "commit": commit(),
        "generator": str(args.generator),
        "env": spec.name,
        "budget": args.budget,
        "seeds": args.seeds,
        "typical_radius": typical_radius(nearest.latent_dim),
        "bounds": {name: {"prior_bound": BOUNDS[name][0], "box": BOUNDS[name][1]} for name in bounds},
        "reference": {
            name: {"dataset_max": float(data[name].max()), "dataset_worlds": count, "fresh": quantiles(fresh_values[name])} for name in names
        },
        "fresh_seeds": [int(fresh.seeds[0]), int(fresh.seeds[-1])],
        "repairs": {},
    }
    for repair in repairs:
        generator = nearest if repair == nearest.repair_name else build_generator(vae, dataset, repair_name=repair)
        drawn = prior_draws(generator, spec, args.fresh, names)
        entry = {"prior_draws": {name: quantiles(drawn[name]) for name in names}, "push": {}}
        for name in names:
            entry["push"][name] = {}
            for bound in bounds:
                runs = [push(generator, spec.metrics.descriptors[name], name, bound, args.budget, seed) for seed in args.seeds]
                entry["push"][name][bound] = runs
                best = [r["full"]["value"] for r in runs]
                norms = [r["full"]["norm"] for r in runs]
                print(
                    f"{repair} {name} {bound}: best {np.round(best, 3)} at |z| {np.round(norms, 1)} "
                    f"(dataset max {result['reference'][name]['dataset_max']:.3f}, fresh p99 {result['reference'][name]['fresh']['p99']:.3f})",
                    flush=True,
                )
        result["repairs"][repair] = entry
    result["wall_seconds"] = time.perf_counter() - started
    payload = {"benchmark": "prior-extremes", "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "machine": describe_machine(), **result}
    path = write_text(RESULTS / "prior-extremes.json", json.dumps(payload, indent=2) + "\n")
    print(f"recorded in {path} ({result['wall_seconds']:.0f} s)")


if __name__ == "__main__":
    main()
