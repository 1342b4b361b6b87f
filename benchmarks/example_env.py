"""The example environment (examples/lavagrid) used as a stranger uses it, through the CLI only (issue 30, item 9).

    pip install -e examples/lavagrid && python benchmarks/example_env.py [--out runs/example-env]

1. ``worldagent train lavagrid``: PPO with its own defaults (the spec declares no overrides).
2. ``worldagent generator train lavagrid`` on 10,000 worlds, then ``worldagent evaluate random``
   of the trained agent and of the scripted uniform-random policy on the same 1,000 worlds
   z ~ N(0, I), 8 episodes each: the trained agent must beat random.
3. ``worldagent reproduce --preset tiny --env lavagrid``: every phase, as CI runs it.

Each command's wall time and CPU time (its process's user + system) are recorded with the load
average: on a shared machine wall time depends on the other work, CPU time much less. Writes
``benchmarks/results/example-env.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shlex
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import RESULTS, describe_machine  # noqa: E402

WORLDS = 1000
DATASET = 10_000
VAE_EPOCHS = 20


def commands(out: Path) -> dict[str, list[str]]:
    """The CLI commands, in order, by step name."""
    evaluate = ["evaluate", "random", "lavagrid", "--generator", str(out / "generator"), "--worlds", str(WORLDS), "--quiet"]
    return {
        "train": ["train", "lavagrid", "--out", str(out / "ppo"), "--quiet"],
        "generator": ["generator", "train", "lavagrid", "--out", str(out / "generator"), "--n", str(DATASET), "--epochs", str(VAE_EPOCHS), "--quiet"],
        "evaluate_ppo": [*evaluate, "--agent", str(out / "ppo"), "--out", str(out / "eval-ppo")],
        "evaluate_random": [*evaluate, "--agent", "random", "--out", str(out / "eval-random")],
        "reproduce_tiny": ["reproduce", "--preset", "tiny", "--env", "lavagrid", "--out", str(out / "tiny"), "--quiet"],
    }


def timed(argv: list[str]) -> dict:
    """Run ``worldagent ARGV``; its wall and CPU seconds, and the 1-minute load average before it."""
    load = os.getloadavg()[0]
    before, start = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    subprocess.run(["worldagent", *argv], check=True)
    wall, after = time.perf_counter() - start, resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"command": shlex.join(["worldagent", *argv]), "wall_s": round(wall, 1), "cpu_s": round(cpu, 1), "load_average_before": round(load, 2)}


def episode_means(store: Path) -> dict[str, float]:
    """Each metric's mean over every episode of every world in a run store."""
    with sqlite3.connect(store) as connection:
        episodes = [episode for (text,) in connection.execute("SELECT episodes FROM evaluations") for episode in json.loads(text)]
    return {"worlds": len(episodes) // 8, "episodes": len(episodes), **{k: round(float(np.mean([e[k] for e in episodes])), 4) for k in episodes[0]}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("runs/example-env"))
    args = parser.parse_args()
    steps = {name: timed(argv) for name, argv in commands(args.out).items()}
    trained, random = episode_means(args.out / "eval-ppo" / "store.sqlite"), episode_means(args.out / "eval-random" / "store.sqlite")
    payload = {
        "benchmark": "example_env",
        "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "machine": describe_machine(),
        "command": "pip install -e examples/lavagrid && python benchmarks/example_env.py",
        "steps": steps,
        "ppo_on_1000_worlds": trained,
        "random_on_1000_worlds": random,
        "ppo_beats_random": trained["return"] > random["return"],
    }
    path = RESULTS / "example-env.json"
    path.write_text(json.dumps(payload, indent=2) + "\n")
    print(json.dumps({"ppo": trained, "random": random, "wall_s": {k: v["wall_s"] for k, v in steps.items()}}, indent=2), f"\n-> {path}")


if __name__ == "__main__":
    main()
