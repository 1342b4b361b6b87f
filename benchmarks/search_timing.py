"""Time one CMA-ES generation and a 1,000-world random evaluation (paper §5.2.2, §6.1.1).

    python benchmarks/search_timing.py --generator runs/generators/racing [--env racing --agent driver]

A generation is 21 latents × 8 episodes, G(z) decoding and repair included, through the same
``LatentObjective`` a campaign uses (store writes excluded). The random evaluation is 1,000
latents z ~ N(0, I) × 8 episodes. The agent is by default the scripted racing driver (episodes
of ~200 steps, like a trained agent's); ``--env`` and ``--agent`` pick others. Compilation is excluded (one warm-up call); best of
``--repeats``. Targets on 2 CPU cores: ≤ 0.2 s per generation, ≤ 5 s per 1,000 worlds.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import record, require_input  # noqa: E402
from worldagent.experiments import setup  # noqa: E402
from worldagent.search.objectives import LatentObjective, Objective  # noqa: E402
from worldagent.search.optimisers import make_optimiser  # noqa: E402


def best_time(fn, repeats: int) -> float:
    fn()  # compile
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--generator", type=Path, default=Path("runs/generators/racing"))
    parser.add_argument("--worlds", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--env", default="racing")
    parser.add_argument("--agent", default="driver", help="a scripted policy's name or a `worldagent train` run directory")
    args = parser.parse_args()

    generator = require_input(args.generator, f"python benchmarks/vae_training.py --env {args.env} --out {args.generator}")
    run = setup(args.env, args.agent, generator, repeats=8)
    generator = run.generator
    objective = LatentObjective(Objective(run.spec.name, "reward", False), run.env, run.policy, generator, run.repeats, run.params, keep_worlds=False)
    cmaes = make_optimiser("cmaes", generator.latent_dim, maximize=False, seed=0)

    def generation():
        z = cmaes.ask(cmaes.batch_size)
        outcomes = objective(z, np.arange(len(z)))
        cmaes.tell(z, np.array([o.score for o in outcomes]))

    z_random = np.random.default_rng(0).standard_normal((args.worlds, generator.latent_dim))
    generation_s = best_time(generation, args.repeats)
    random_s = best_time(lambda: objective(z_random, np.arange(args.worlds)), args.repeats)
    print(f"one CMA-ES generation (21 worlds x 8 episodes, decode + repair + ask/tell): {generation_s:.3f} s")
    print(f"random evaluation ({args.worlds} worlds x 8 episodes): {random_s:.2f} s")
    result = {
        "generation_seconds": round(generation_s, 4),
        "random_evaluation_seconds": round(random_s, 3),
        "worlds": args.worlds,
        "env": run.spec.name,
        "agent": args.agent,
    }
    print(f"recorded in {record('search_timing', result)}")


if __name__ == "__main__":
    main()
