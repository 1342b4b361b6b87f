"""Wall time of N seeds trained one after another (``training.train``) against as one program (``many.train_many``), issue 28.

    python benchmarks/many_runs.py                              # 1 and 5 seeds of PPO, ACKTR (racing) and DQN (harvest), twice
    python benchmarks/many_runs.py --seeds 1 5 10 --repeats 1 --racing-episodes 1000

Each measurement runs in a fresh process (so both ways pay their compilation, as a user does) and
times the training calls only (pool building and imports excluded). PPO and ACKTR train on racing
(the spec's settings) on a procedural pool of ``--pool`` tracks, DQN on harvest (its default
config, agent 0 tags) on a pool of ``--pool`` maps, at the small budgets given. Sequential and
together run back to back, ``--repeats`` times, each with the load average read from
``os.getloadavg`` before and after, since the machine may be shared. Each together-run's agents are
compared with the sequential ones of the same seeds: the largest parameter difference is recorded
(they are equal up to float rounding, which grows with training). Results:
``benchmarks/results/many-runs.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import RESULTS, describe_machine  # noqa: E402

ENVS = {"ppo": "racing", "acktr": "racing", "dqn": "harvest"}


def measure(algo: str, mode: str, seeds: int, episodes: int, pool_size: int, out: Path) -> dict:
    """Train ``seeds`` runs of ``algo`` one way in this process; wall seconds of the training calls."""
    import jax
    import numpy as np

    from worldagent.agents.algorithms import training_config
    from worldagent.agents.distributions import world_distribution
    from worldagent.agents.many import ManyRun, train_many
    from worldagent.agents.training import train

    env = ENVS[algo]
    pool = world_distribution(env, "generator", size=pool_size, seed=0)
    config = training_config(env, algo, episodes=episodes)
    load_before = os.getloadavg()
    cpu_before, start = _cpu_seconds(), time.perf_counter()
    if mode == "sequential":
        results = [train(env, algo, config, pool, out / f"seed{s}", seed=s, progress=False, resume=False) for s in range(seeds)]
    else:
        results = train_many(
            env, algo, config, [ManyRun(out / f"seed{s}", seed=s, distribution=pool) for s in range(seeds)], progress=False, resume=False
        )
    wall, cpu = time.perf_counter() - start, _cpu_seconds() - cpu_before
    # the first chunk of each program includes its compilation: the rest is the steady rate
    first, last = [float(r.curve["wall_seconds"][0]) for r in results], [float(r.curve["wall_seconds"][-1]) for r in results]
    steady = sum(b - a for a, b in zip(first, last)) if mode == "sequential" else max(last) - first[0]
    params = [[np.asarray(x) for x in jax.tree_util.tree_leaves(r.agent.params)] for r in results]
    np.savez(out / f"{mode}-params.npz", *[x for run in params for x in run])
    return {
        "wall_s": round(wall, 1),
        "cpu_s": round(cpu, 1),
        "cores_busy": round(cpu / wall, 2),
        "after_first_chunk_s": round(steady, 1),
        "episodes": [r.episodes for r in results],
        "env_steps": sum(r.env_steps for r in results),
        "load_before": [round(x, 2) for x in load_before],
        "load_after": [round(x, 2) for x in os.getloadavg()],
    }


def _cpu_seconds() -> float:
    """User + system CPU seconds of this process so far (all its threads)."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def run_child(algo: str, mode: str, seeds: int, episodes: int, pool_size: int, out: Path) -> dict:
    command = [sys.executable, __file__, "--child", algo, mode, str(seeds), str(episodes), str(pool_size), str(out)]
    return json.loads(subprocess.run(command, check=True, capture_output=True, text=True).stdout.strip().splitlines()[-1])


def max_difference(out: Path) -> float:
    """Largest |parameter difference| between the together and the sequential agents of the same seeds."""
    import numpy as np

    a, b = np.load(out / "sequential-params.npz"), np.load(out / "together-params.npz")
    return float(max(np.abs(a[k].astype(np.float64) - b[k].astype(np.float64)).max() for k in a.files))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algos", nargs="+", default=list(ENVS), choices=list(ENVS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 5])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--racing-episodes", type=int, default=400)
    parser.add_argument("--harvest-episodes", type=int, default=120)
    parser.add_argument("--pool", type=int, default=1000)
    args = parser.parse_args()
    episodes = {"ppo": args.racing_episodes, "acktr": args.racing_episodes, "dqn": args.harvest_episodes}
    rows = []
    for repeat in range(args.repeats):
        for algo in args.algos:
            for seeds in args.seeds:
                row = {"algorithm": algo, "env": ENVS[algo], "seeds": seeds, "episodes_per_run": episodes[algo], "repeat": repeat}
                with tempfile.TemporaryDirectory() as tmp:
                    for mode in ("sequential", "together"):
                        row[mode] = run_child(algo, mode, seeds, episodes[algo], args.pool, Path(tmp))
                    row["speedup"] = round(row["sequential"]["wall_s"] / row["together"]["wall_s"], 2)
                    row["speedup_after_first_chunk"] = round(
                        row["sequential"]["after_first_chunk_s"] / max(row["together"]["after_first_chunk_s"], 1e-9), 2
                    )
                    row["max_param_difference"] = max_difference(Path(tmp))
                print(json.dumps(row), flush=True)
                rows.append(row)
                path = write(args, rows)
    print(f"recorded in {path}")


def write(args, rows: list[dict]) -> Path:
    """The results so far, to ``benchmarks/results/many-runs.json``."""
    payload = {
        "benchmark": "many-runs",
        "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "machine": describe_machine(),
        "command": "python benchmarks/many_runs.py " + " ".join(sys.argv[1:]),
        "note": (
            "Each measurement a fresh process (compilation included, imports and pool building excluded); sequential = training.train per seed, "
            "together = many.train_many (one vmapped program). The machine was shared with another worker's benchmark: load averages "
            "(1, 5, 15 min) are recorded before and after each measurement, and the timings are noisy. after_first_chunk_s: the training "
            "time less each program's first chunk (which includes its compilation; sequential runs compile once, in their first run). "
            "cores_busy: CPU seconds / wall seconds of the training calls (2 = both cores busy)."
        ),
        "pool": f"procedural, {args.pool} worlds, seeds 0..{args.pool - 1}",
        "runs": rows,
    }
    from worldagent.files import write_text

    return write_text(RESULTS / "many-runs.json", json.dumps(payload, indent=2) + "\n")


if __name__ == "__main__":
    if sys.argv[1:2] == ["--child"]:
        algo, mode, seeds, episodes, pool, out = sys.argv[2:8]
        print(json.dumps(measure(algo, mode, int(seeds), int(episodes), int(pool), Path(out))))
    else:
        main()
