"""What the curricula's buffers favoured at the end of training: the env's world descriptors of each
arm's top-scored buffer latents against random G(z) worlds.

    python benchmarks/studies/curriculum_buffers.py --env harvest --work runs/curriculum-harvest --arms plr accel target
    # -> benchmarks/results/curriculum-buffers-harvest.json

For every seed's run directory ``--work/<arm>/s<seed>`` it reads the last buffer snapshot
(``curricula.snapshots``), decodes the ``--top`` latents of highest score with the benchmark's
generator (read from ``--work``'s ``curriculum-<env>.json``, else ``--generator``), and averages
each of ``spec.metrics.descriptors`` over them, and ``new_share``, the share of them that are in
no dataset world (by cells; with an open repair, new worlds); ``random`` is the same over
``--random`` worlds z ~ N(0, I). A curriculum that trains on worlds unlike the evaluation's shows here.
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

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: machine and the scripts imported
from machine import RESULTS, describe_machine, require_input  # noqa: E402
from worldagent.curricula.snapshots import load_snapshots  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.files import write_text  # noqa: E402
from worldagent.influence.statistics import mean_and_ci  # noqa: E402
from worldagent.worlds.generator import load_generator  # noqa: E402


def descriptor_means(spec, G, latents: np.ndarray) -> dict[str, float]:
    """The mean of every descriptor of ``spec`` over the worlds G decodes ``latents`` to."""
    worlds = G(jnp.asarray(latents, jnp.float32))
    one = [jax.tree_util.tree_map(lambda x, i=i: x[i], worlds) for i in range(len(latents))]
    return {name: float(np.mean([f(w) for w in one])) for name, f in spec.metrics.descriptors.items()}


def new_share(spec, G, dataset, latents: np.ndarray) -> float:
    """The share of the worlds G decodes ``latents`` to whose cells equal no world of ``dataset``."""
    known = {row.tobytes() for row in dataset.cells}
    cells = np.asarray(spec.cells(G(jnp.asarray(latents, jnp.float32))), np.uint8)
    return float(np.mean([row.tobytes() not in known for row in cells]))


def favoured(run_dir: Path, top: int) -> np.ndarray | None:
    """The ``top`` highest-scored latents of the run's last buffer snapshot (None: no snapshot)."""
    snapshots = load_snapshots(run_dir)
    if not snapshots:
        return None
    last = snapshots[-1]
    filled = np.asarray(last["count"]) > 0
    z, score = np.asarray(last["z"])[filled], np.asarray(last["score"])[filled]
    return z[np.argsort(-score)[:top]]


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="harvest", choices=registry.names())
    parser.add_argument("--work", type=Path, required=True, help="a benchmarks/curriculum.py --work directory")
    parser.add_argument("--arms", nargs="+", default=["plr", "accel", "target"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--top", type=int, default=50, help="latents of highest score per buffer")
    parser.add_argument("--random", type=int, default=500, help="random G(z) worlds to compare with")
    parser.add_argument("--generator", type=Path, default=None, help="default: the one the benchmark's JSON names")
    parser.add_argument("--results", type=Path, default=None)
    args = parser.parse_args(argv)
    spec = registry.get(args.env)
    gen_dir = args.generator or Path(json.loads((RESULTS / f"curriculum-{args.env}.json").read_text())["generator"])
    G, _, dataset = load_generator(require_input(gen_dir, f"python benchmarks/curriculum.py --env {args.env}"))
    rows = {"random": descriptor_means(spec, G, np.random.default_rng(0).standard_normal((args.random, G.latent_dim)))}
    per_seed = {}
    for arm in args.arms:
        found = {s: favoured(args.work / arm / f"s{s}", args.top) for s in args.seeds}
        per_seed[arm] = {
            str(s): {**descriptor_means(spec, G, z), "new_share": new_share(spec, G, dataset, z)} for s, z in found.items() if z is not None
        }
        if per_seed[arm]:
            rows[arm] = {name: mean_and_ci([v[name] for v in per_seed[arm].values()]) for name in (*spec.metrics.descriptors, "new_share")}
    payload = {
        "benchmark": "curriculum-buffers",
        "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "machine": describe_machine(),
        "command": "python benchmarks/studies/curriculum_buffers.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "env": args.env,
        "generator": str(gen_dir),
        "top": args.top,
        "summary": rows,
        "per_seed": per_seed,
    }
    path = args.results or RESULTS / f"curriculum-buffers-{args.env}.json"
    write_text(path, json.dumps(payload, indent=1))
    for arm, row in rows.items():
        print(arm, {k: round(v if arm == "random" else v["mean"], 3) for k, v in row.items()})
    print(f"recorded in {path}")
    return payload


if __name__ == "__main__":
    main()
