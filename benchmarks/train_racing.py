"""Train racing agents at the paper's budget (10,000 episodes, §5.3) over seeds × algorithms × observations, time and evaluate them.

    python benchmarks/train_racing.py --algos ppo acktr --observations surroundings --seeds 0 1 2 3 4
    python benchmarks/train_racing.py --algos acktr --seeds 0 1 2 3 4 --together   # the seeds as one program (many.train_many)

Training draws each episode's world uniformly from a procedural pool of 10,000 tracks (seeds
0..9999, the paper's dataset). Evaluation (paper §6.1.1): ``--eval-worlds`` worlds sampled from
the generator — G(z), z ~ N(0, I), from ``runs/generators/racing`` if that generator exists,
else fresh procedural tracks (seeds 1,000,000 + i, never trained on) — ``--repeats`` episodes
each with the stochastic policy, one jitted ``vmap(vmap(rollout))``. Each run records wall time
and env steps/s of training, crash rate, lap rate, the rate of parked episodes (300 steps
without a lap or a crash) and the mean return, raw and normalised (the spec's
``metrics.normalise``).

All runs go to ``benchmarks/results/<name>-<backend>.json`` (default name ``train-racing``) with
the machine (``machine.record``): one row per (algorithm, observation, options, seed, episodes,
evaluation), so later invocations add seeds to the same file; and per algorithm × observation,
the seeds whose lap rate reaches ``LAP_TARGET`` (issue 13's target).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import jax  # noqa: E402
import numpy as np  # noqa: E402

from machine import RESULTS, describe_machine, record  # noqa: E402
from worldagent.agents.algorithms import training_config  # noqa: E402
from worldagent.agents.distributions import LatentWorlds, world_distribution  # noqa: E402
from worldagent.agents.many import ManyRun, train_many  # noqa: E402
from worldagent.agents.training import train  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.envs.core import rollout  # noqa: E402
from worldagent.envs.racing.metrics import racing_return_bounds  # noqa: E402

GENERATOR_DIR = Path("runs/generators/racing")
SPEC = registry.get("racing")
LAP_TARGET = 0.9
DISTRIBUTION = "generator (procedural pool of 10,000, seeds 0..9999)"
KEY_FIELDS = (
    "algorithm",
    "observation",
    "options",
    "overrides",
    "note",
    "seed",
    "episodes_budget",
    "eval_worlds",
    "repeats",
    "eval_source",
    "training",
)


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


def evaluation_worlds(key, n: int):
    """(worlds, description): G(z) from the racing generator if present, else procedural."""
    if (GENERATOR_DIR / "generator.json").is_file():
        dist = world_distribution("racing", "vae", generator_dir=GENERATOR_DIR)
        assert isinstance(dist, LatentWorlds)
        return dist.sample_batch(key, n), f"G(z), z ~ N(0, I), generator {GENERATOR_DIR}"
    pool = world_distribution("racing", "generator", size=n, seed=1_000_000)
    return pool.worlds, f"procedural tracks, seeds 1,000,000..{1_000_000 + n - 1} (no generator at {GENERATOR_DIR})"


def result_row(algo, options, overrides, config, seed, args, trained: dict, policy, env, params, eval_key) -> dict:
    """Evaluate ``policy`` on the evaluation worlds; the run's row (``trained``: its training figures)."""
    start = time.perf_counter()
    key_worlds, key_eval = jax.random.split(eval_key)
    worlds, source = evaluation_worlds(key_worlds, args.eval_worlds)
    metrics = evaluate(policy, worlds, args.repeats, key_eval, env, params)
    raw = metrics["return"]
    parked = (metrics["steps"] >= int(params.max_steps)) & ~metrics["crashed"] & ~metrics["lap_completed"]
    low, high = racing_return_bounds(params)
    return {
        "algorithm": algo,
        "observation": options["observation"],
        "options": options,
        "overrides": overrides,
        "note": args.note,
        "seed": seed,
        "episodes_budget": args.episodes,
        "eval_worlds": args.eval_worlds,
        "repeats": args.repeats,
        "eval_source": source,
        "config": config.to_dict(),
        **trained,
        "lap_rate": round(float(metrics["lap_completed"].mean()), 4),
        "crash_rate": round(float(metrics["crashed"].mean()), 4),
        "parked_rate": round(float(parked.mean()), 4),
        "mean_return_raw": round(float(raw.mean()), 2),
        "mean_return_normalised": round(float(SPEC.metrics.normalise(raw, params).mean()), 4),
        "normalisation": f"clip((raw - {low}) / ({high} - {low}), 0, 1)",
        "mean_steps": round(float(metrics["steps"].mean()), 1),
        "eval_seconds": round(time.perf_counter() - start, 1),
        "policy": "stochastic (samples its action distribution)",
    }


def run_seeds(algo: str, options: dict, args, pool, out_root: Path):
    """Train ``args.seeds`` agents with the host driver (checkpoints, resumable), one after another or, with
    ``--together``, as one program (``many.train_many``); evaluate each and yield its row as it is ready."""
    env, params = SPEC.make_env(options)
    overrides = args.overrides.get(algo, {})
    config = training_config(SPEC, algo, episodes=args.episodes, **overrides)
    tag = "-".join(f"{k}={v}" for k, v in sorted({**options, **overrides}.items())) + "".join(
        c if c.isalnum() else "_" for c in f"-{args.note}" if args.note
    )
    out_dir = lambda seed: out_root / f"{algo}-{tag}-seed{seed}-{args.episodes}"  # noqa: E731
    common = {"options": options, "progress": not args.quiet, "resume": not args.no_resume}
    if args.together:
        runs = [ManyRun(out_dir(seed), seed=seed, distribution=pool, distribution_spec=DISTRIBUTION) for seed in args.seeds]
        results = zip(args.seeds, train_many(SPEC, algo, config, runs, max_together=args.max_together, **common))
        how = f"many.train_many, {len(args.seeds)} seeds as one program (train_seconds: all of them)"
    else:
        results = ((seed, train(SPEC, algo, config, pool, out_dir(seed), seed=seed, distribution_spec=DISTRIBUTION, **common)) for seed in args.seeds)
        how = "host driver (training.train), one seed"
    for seed, result in results:
        trained = {
            "training": how,
            "train_seconds": round(result.wall_seconds, 1),
            "resumed_from_update": result.resumed_from_update,
            "episodes": result.episodes,
            "env_steps": result.env_steps,
            "env_steps_per_s": round(result.env_steps / result.wall_seconds),
            "final_curve": {k: float(v[-1]) for k, v in result.curve.items() if len(v)},
        }
        yield result_row(algo, options, overrides, config, seed, args, trained, result.agent.policy, env, params, jax.random.key(args.eval_seed))


def summarise(runs: list[dict]) -> list[dict]:
    """Per algorithm × observation × options × budget: seeds, how many lap at ``LAP_TARGET``, means."""
    groups: dict[str, list[dict]] = {}
    for run in runs:
        key = json.dumps(
            [
                run["algorithm"],
                run["options"],
                run.get("overrides", {}),
                run.get("note", ""),
                run["episodes_budget"],
                run["eval_worlds"],
                run["repeats"],
            ]
        )
        groups.setdefault(key, []).append(run)
    table = []
    for group in groups.values():
        first = group[0]
        mean = lambda name: round(float(np.mean([r[name] for r in group])), 4)  # noqa: E731
        table.append(
            {
                "algorithm": first["algorithm"],
                "options": first["options"],
                "overrides": first.get("overrides", {}),
                "note": first.get("note", ""),
                "episodes_budget": first["episodes_budget"],
                "eval": f"{first['eval_worlds']} worlds x {first['repeats']}",
                "seeds": sorted(r["seed"] for r in group),
                "seeds_at_lap_target": sum(r["lap_rate"] >= LAP_TARGET for r in group),
                "seeds_parked": sum(r["parked_rate"] > 0.5 for r in group),
                **{f"mean_{name}": mean(name) for name in ("lap_rate", "crash_rate", "parked_rate", "mean_return_normalised", "train_seconds")},
            }
        )
    return table


def previous_runs(name: str) -> list[dict]:
    """Runs already recorded under ``name`` on this backend (so invocations add to one file)."""
    path = RESULTS / f"{name}-{describe_machine()['backend']}.json"
    return json.loads(path.read_text()).get("runs", []) if path.is_file() else []


def parse_overrides(texts: list[str]) -> dict[str, dict]:
    """``{algo: {field: value}}`` from ``ALGO.FIELD=JSON`` strings."""
    overrides: dict[str, dict] = {}
    for text in texts:
        name, _, value = text.partition("=")
        algo, _, field = name.partition(".")
        overrides.setdefault(algo, {})[field] = json.loads(value)
    return overrides


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algos", "--algo", nargs="+", choices=SPEC.algorithms, default=list(SPEC.algorithms))
    parser.add_argument("--observations", nargs="+", default=["route"], help="racing observations (route, surroundings)")
    parser.add_argument("--option", action="append", default=[], help="another racing option NAME=VALUE, e.g. reach=96")
    parser.add_argument("--set", action="append", default=[], help="a config field ALGO.FIELD=JSON, e.g. ppo.crash_warmup=0.3")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--note", default="", help="what distinguishes these runs beyond options and config (kept in each row)")
    parser.add_argument("--episodes", type=int, default=10_000)
    parser.add_argument("--eval-worlds", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=8)
    parser.add_argument("--eval-seed", type=int, default=1, help="key of the evaluation worlds and episodes (the same for every run)")
    parser.add_argument("--name", default="train-racing", help="results file: benchmarks/results/NAME-<backend>.json")
    parser.add_argument("--out-root", type=Path, default=Path("runs/agents/train-racing"))
    parser.add_argument("--no-resume", action="store_true")
    parser.add_argument("--together", action="store_true", help="train the seeds as one vmapped program (many.train_many)")
    parser.add_argument("--max-together", type=int, default=None, help="with --together: seeds per program at most (default: from the device)")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args()
    args.overrides = parse_overrides(args.set)

    start = time.perf_counter()
    pool = world_distribution("racing", "generator", size=10_000, seed=0)
    print(f"pool of 10,000 tracks in {time.perf_counter() - start:.0f} s")
    for observation in args.observations:
        options = SPEC.parse_options([f"observation={observation}", *args.option])
        for algo in args.algos:
            for run in run_seeds(algo, options, args, pool, args.out_root):
                print(
                    f"{algo} {observation} {options} {args.overrides.get(algo, {})} seed {run['seed']}: {run['episodes']:,} episodes, "
                    f"{run['env_steps']:,} steps, {run['train_seconds']:.0f} s; eval {args.eval_worlds} x {args.repeats}: lap {run['lap_rate']:.3f}, "
                    f"crash {run['crash_rate']:.3f}, parked {run['parked_rate']:.3f}, normalised {run['mean_return_normalised']:.3f}",
                    flush=True,
                )
                key = [run[f] for f in KEY_FIELDS]
                runs = [r for r in previous_runs(args.name) if [r.get(f) for f in KEY_FIELDS] != key] + [run]  # reread: runs in parallel add theirs
                path = record(args.name, {"lap_target": LAP_TARGET, "summary": summarise(runs), "runs": runs})
    print(f"recorded in {path}")


if __name__ == "__main__":
    main()
