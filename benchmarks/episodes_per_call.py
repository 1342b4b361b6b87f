"""CPU seconds per episode of each env's agents at each size of the evaluator's compiled calls.

    python benchmarks/episodes_per_call.py                      # the quick run's agents (runs/quick)
    python benchmarks/episodes_per_call.py --run RUN --sizes 32 64 128 256

Every compiled evaluation call plays one fixed number of episodes (``evaluation.local``: batch
invariance), so a batch smaller than a call is padded: a CMA-ES generation (21 worlds x 8 = 168
episodes), a BO round (4 worlds x 8 = 32) and a reported world's confirmation (64) each cost one
whole call. This times ``evaluate`` on 512 episodes of random G(z)-free procedural worlds at each
call size (compilation excluded) and prints what those three batches cost at each size. An env whose
episodes all run the same length (harvest's 1,000 steps) plays them as fast in small calls; one
whose episodes end at different steps (racing) waits for the slowest of each call. The result
chooses ``Environment.cpu_episodes_per_call``; recorded in ``results/episodes-per-call-<backend>.json``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import QUICK_RUN, record, require_input  # noqa: E402
from worldagent.agents.loaders import load_agent  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.evaluation.local import evaluate  # noqa: E402

BATCHES = {"cmaes generation": 168, "bo round": 32, "confirmation": 64}
EPISODES, REPEATS = 512, 8


def seconds_per_episode(spec, policy, env, params, size: int) -> float:
    os.environ["WORLDAGENT_EPISODES_PER_CALL"] = str(size)
    worlds = jax.tree_util.tree_map(np.asarray, spec.generate(np.arange(10**6, 10**6 + EPISODES // REPEATS)))
    evaluate(env, policy, worlds, REPEATS, jax.random.key(0), params)  # compiles
    start = time.process_time()
    evaluate(env, policy, worlds, REPEATS, jax.random.key(1), params)
    return (time.process_time() - start) / EPISODES


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=Path, default=Path("runs/quick"), help="a reproduce run directory: its agents are timed")
    parser.add_argument("--envs", nargs="*", default=["racing", "harvest"])
    parser.add_argument("--sizes", type=int, nargs="*", default=[32, 64, 128, 256])
    args = parser.parse_args(argv)
    envs = {}
    for name in args.envs:
        spec = registry.get(name)
        agent = require_input(args.run / name / "agent", QUICK_RUN)
        options = spec.reproduce_options
        env, params = spec.make_env(options)
        policy = load_agent(spec, agent, options=options)
        per_episode = {size: seconds_per_episode(spec, policy, env, params, size) for size in args.sizes}
        batches = {batch: {size: round(-(-count // size) * size * per_episode[size], 3) for size in args.sizes} for batch, count in BATCHES.items()}
        envs[name] = {"cpu_s_per_episode": {s: round(v, 5) for s, v in per_episode.items()}, "cpu_s_per_batch": batches}
        print(name, {s: f"{v * 1e3:.1f} ms" for s, v in per_episode.items()}, batches, flush=True)
    os.environ.pop("WORLDAGENT_EPISODES_PER_CALL")
    return {"run": str(args.run), "episodes": EPISODES, "envs": envs}


if __name__ == "__main__":
    record("episodes-per-call", main())
