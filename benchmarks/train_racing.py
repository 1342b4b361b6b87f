"""Train a racing agent at the paper's budget (10,000 episodes, §5.3), time it, and evaluate it.

    python benchmarks/train_racing.py --algo ppo --out runs/agents/racing-ppo

Training draws each episode's world uniformly from a procedural pool of 10,000 tracks (seeds
0..9999, the paper's dataset). Evaluation (paper §6.1.1): 1,000 worlds sampled from the
generator — G(z), z ~ N(0, I), from ``runs/generators/racing`` if that generator exists, else
fresh procedural tracks (seeds 1,000,000 + i, never trained on) — 8 episodes each with the
stochastic policy, one jitted ``vmap(vmap(rollout))``. Records wall time and env steps/s of
training, crash rate, lap rate and the mean return, raw and normalised (the spec's
``metrics.normalise``), with the machine (``machine.record``).

Algorithms and their default configs come from ``worldagent.agents.algorithms``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import jax  # noqa: E402
import numpy as np  # noqa: E402

from machine import record  # noqa: E402
from worldagent.agents.algorithms import training_config  # noqa: E402
from worldagent.agents.distributions import LatentWorlds, world_distribution  # noqa: E402
from worldagent.agents.training import train  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.envs.core import rollout  # noqa: E402
from worldagent.envs.racing.metrics import racing_return_bounds  # noqa: E402

GENERATOR_DIR = Path("runs/generators/racing")
SPEC = registry.get("racing")


def evaluate(policy, worlds, repeats: int, key, env, params) -> dict[str, np.ndarray]:
    """Per-episode metrics [B, repeats] of ``policy`` on a batch of B worlds."""

    def one(world, k):
        final, _ = rollout(env, policy, k, world, params, int(params.max_steps))
        return env.metrics(final)

    def per_world(world, k):
        return jax.vmap(one, in_axes=(None, 0))(world, jax.random.split(k, repeats))

    n = jax.tree_util.tree_leaves(worlds)[0].shape[0]
    out = jax.jit(jax.vmap(per_world))(worlds, jax.random.split(key, n))
    return {k: np.asarray(v) for k, v in out.items()}


def evaluation_worlds(key, n: int, env):
    """(worlds, description): G(z) from the lead's racing generator if present, else procedural."""
    if (GENERATOR_DIR / "generator.json").is_file():
        dist = world_distribution("racing", "vae", generator_dir=GENERATOR_DIR)
        assert isinstance(dist, LatentWorlds)
        return dist.sample_batch(key, n), f"G(z), z ~ N(0, I), generator {GENERATOR_DIR}"
    pool = world_distribution("racing", "generator", size=n, seed=1_000_000)
    return pool.worlds, "procedural tracks, seeds 1,000,000..1,000,999 (no generator at runs/generators/racing)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", choices=SPEC.algorithms, default=SPEC.default_algorithm)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=10_000)
    parser.add_argument("--eval-worlds", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=8)
    parser.add_argument("--no-resume", action="store_true")
    args = parser.parse_args()

    env, params = SPEC.make_env()
    out = args.out or Path(f"runs/agents/racing-{args.algo}")
    config = training_config(SPEC, args.algo, episodes=args.episodes)
    start = time.perf_counter()
    pool = world_distribution("racing", "generator", size=10_000, seed=0)
    pool_seconds = time.perf_counter() - start
    result = train(
        SPEC,
        args.algo,
        config,
        pool,
        out,
        seed=args.seed,
        progress=True,
        resume=not args.no_resume,
        distribution_spec="generator (procedural pool of 10,000, seeds 0..9999)",
    )
    steps_per_s = result.env_steps / result.wall_seconds

    start = time.perf_counter()
    key_worlds, key_eval = jax.random.split(jax.random.key(args.seed + 1))
    worlds, source = evaluation_worlds(key_worlds, args.eval_worlds, env)
    metrics = evaluate(result.agent.policy, worlds, args.repeats, key_eval, env, params)
    eval_seconds = time.perf_counter() - start
    raw = metrics["return"]
    low, high = racing_return_bounds(params)
    summary = {
        "algorithm": args.algo,
        "config": config.to_dict(),
        "seed": args.seed,
        "pool_seconds": round(pool_seconds, 2),
        "train_seconds": round(result.wall_seconds, 2),
        "resumed_from_update": result.resumed_from_update,
        "episodes": result.episodes,
        "env_steps": result.env_steps,
        "env_steps_per_s": round(steps_per_s),
        "evaluation": {
            "worlds": args.eval_worlds,
            "repeats": args.repeats,
            "source": source,
            "policy": "stochastic (samples its action distribution)",
            "crash_rate": round(float(metrics["crashed"].mean()), 4),
            "lap_rate": round(float(metrics["lap_completed"].mean()), 4),
            "mean_return_raw": round(float(raw.mean()), 2),
            "mean_return_normalised": round(float(SPEC.metrics.normalise(raw, params).mean()), 4),
            "normalisation": f"clip((raw - {low}) / ({high} - {low}), 0, 1), envs/racing/metrics.py",
            "mean_steps": round(float(metrics["steps"].mean()), 1),
            "seconds": round(eval_seconds, 2),
        },
        "final_curve": {k: float(v[-1]) for k, v in result.curve.items() if len(v)},
    }
    ev = summary["evaluation"]
    print(
        f"{args.algo}: {result.episodes:,} episodes, {result.env_steps:,} env steps in {result.wall_seconds:.0f} s "
        f"({steps_per_s:,.0f} steps/s); eval on {args.eval_worlds} worlds x {args.repeats}: crash {ev['crash_rate']:.3f}, "
        f"lap {ev['lap_rate']:.3f}, return {ev['mean_return_raw']:.1f} raw / {ev['mean_return_normalised']:.3f} normalised"
    )
    print(f"recorded in {record(f'train_racing_{args.algo}', summary)}")


if __name__ == "__main__":
    main()
