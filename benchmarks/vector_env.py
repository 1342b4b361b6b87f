"""Steps per second of the Gymnasium vector env, against CarRacing-v3, and the single env's reset time.

    python benchmarks/vector_env.py                          # 1, 64, 1024 envs; CarRacing-v3; resets
    python benchmarks/vector_env.py --envs 64 --steps 5000 --no-carracing

The vector env is ``gymnasium.make_vec("worldagent/ParticleRacing-v0", num_envs=N)``, driven as a
training loop drives it: a Python loop of ``envs.step(actions)`` with uniform random actions drawn
by numpy on the host, numpy arrays back, SAME_STEP autoreset on new pool tracks. So unlike
``env_throughput.py`` (whole rollouts inside one ``lax.scan``), the figures include the per-step
cost of Python, dispatch and host transfers. Timing excludes compilation (a warm-up) and takes
the best of ``--repeats`` runs. The single env's reset (``gymnasium.make``) is timed over
``--resets`` resets once its track pool exists, and against generating a track per reset
(``options={"track_seed": s}``, what every reset did before the pool). The pool is cached in a
temporary folder, so its one-off generation is timed too. Results go to
``benchmarks/results/vector-env.json`` with the machine's description.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import gymnasium
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import worldagent  # noqa: E402, F401  (registers worldagent/ParticleRacing-v0)
from env_throughput import time_carracing  # noqa: E402
from machine import RESULTS, describe_machine  # noqa: E402
from worldagent.envs.vector import POOL_SIZE  # noqa: E402
from worldagent.files import write_text  # noqa: E402

ENV_ID = "worldagent/ParticleRacing-v0"


def vector_steps_per_second(num_envs: int, steps: int, repeats: int, cache_dir: Path) -> float:
    """Best-of-``repeats`` env steps per second of ``steps`` random-action ``envs.step`` calls."""
    envs = gymnasium.make_vec(ENV_ID, num_envs=num_envs, cache_dir=cache_dir)
    envs.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(10):  # compile and warm up
        envs.step(rng.integers(0, envs.single_action_space.n, num_envs))
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(steps):
            envs.step(rng.integers(0, envs.single_action_space.n, num_envs))
        best = min(best, time.perf_counter() - start)
    envs.close()
    return num_envs * steps / best


def reset_milliseconds(resets: int, cache_dir: Path) -> dict:
    """The single env's first reset (the pool generated and cached), then mean reset times from the pool and with generation."""
    env = gymnasium.make(ENV_ID, cache_dir=cache_dir)
    start = time.perf_counter()
    env.reset(seed=0)
    first = time.perf_counter() - start
    for _ in range(10):
        env.reset()
    start = time.perf_counter()
    for _ in range(resets):
        env.reset()
    pooled = (time.perf_counter() - start) / resets
    env.reset(options={"track_seed": 0})  # the first generation pays numpy's one-off costs
    generating = 10
    start = time.perf_counter()
    for seed in range(1, generating + 1):
        env.reset(options={"track_seed": seed})
    generated = (time.perf_counter() - start) / generating
    env.close()
    return {
        "pool_size": POOL_SIZE,
        "first_reset_s_generating_pool": round(first, 3),
        "reset_ms_from_pool": round(pooled * 1e3, 4),
        "resets_timed": resets,
        "reset_ms_generating_track": round(generated * 1e3, 2),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", default="1,64,1024", help="comma-separated numbers of envs")
    parser.add_argument("--steps", type=int, default=2000, help="envs.step calls per timed run (1024 envs and up use a quarter)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--resets", type=int, default=200, help="single-env resets timed")
    parser.add_argument("--carracing-steps", type=int, default=1000)
    parser.add_argument("--no-carracing", action="store_true", help="skip timing Gymnasium's CarRacing-v3")
    args = parser.parse_args()

    machine = describe_machine()
    print(machine)
    result = {"steps": args.steps, "repeats": args.repeats, "autoreset_mode": "SameStep", "actions": "uniform random, numpy on the host"}
    with tempfile.TemporaryDirectory(prefix="worldagent-cache-") as cache_dir:
        resets = reset_milliseconds(args.resets, Path(cache_dir))
        print(
            f"single env: reset {resets['reset_ms_from_pool']:.3f} ms from the pool, {resets['reset_ms_generating_track']:.1f} ms generating a track"
        )
        rates = {}
        for num_envs in (int(n) for n in args.envs.split(",")):
            steps = args.steps // 4 if num_envs >= 1024 else args.steps
            rates[str(num_envs)] = round(vector_steps_per_second(num_envs, steps, args.repeats, Path(cache_dir)))
            print(f"vector env {num_envs:>5} envs: {rates[str(num_envs)]:>12,} steps/s")
    result["vector_env_steps_per_s"] = rates
    result["single_env_reset"] = resets
    if not args.no_carracing:
        rate = time_carracing(args.carracing_steps)
        if rate is not None:
            result["carracing_v3_steps_per_s"] = round(rate, 1)
            print(f"CarRacing-v3     1 env : {rate:>12,.1f} steps/s")
    payload = {"benchmark": "vector_env", "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "machine": machine, **result}
    path = write_text(RESULTS / "vector-env.json", json.dumps(payload, indent=2) + "\n")
    print(f"recorded in {path}")


if __name__ == "__main__":
    main()
