"""Training speed of PPO's memoryless MLP against its recurrent students (issue 42), same env, same config.

    python benchmarks/recurrent_ppo_speed.py --env racing --updates 8

Each arm compiles once (``train_chunk`` of ``--updates`` updates, timed after a warm-up chunk) and
reports env steps per second of training (rollout + learning); arms alternate, best of ``--repeats``.
Writes ``benchmarks/results/recurrent-ppo-speed-<env>-m<memory>-<backend>.json`` with the machine.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax

from worldagent.agents.algorithms import training_config
from worldagent.agents.distributions import world_distribution
from worldagent.agents.ppo import make_train
from worldagent.envs import registry

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import RESULTS, describe_machine  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="racing")
    parser.add_argument("--updates", type=int, default=8, help="updates per timed chunk")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--memory-size", type=int, default=256)
    args = parser.parse_args()
    spec = registry.get(args.env)
    env, params = spec.make_env()
    pool = world_distribution(spec, "generator", size=64, seed=0)
    arms = {"mlp": None, "lstm": "lstm", "gru": "gru"}
    trainers, states, best = {}, {}, {}
    for name, cell in arms.items():
        config = training_config(spec, "ppo", episodes=10**6, recurrent=cell, memory_size=args.memory_size)
        trainers[name] = make_train(config, env, params, pool)
        states[name], _ = trainers[name].train_chunk(trainers[name].init(jax.random.key(0)), args.updates)  # compile, warm up
        jax.block_until_ready(states[name])
        steps_per_update = config.num_envs * config.num_steps
    for _ in range(args.repeats):
        for name in arms:
            start = time.perf_counter()
            states[name], _ = trainers[name].train_chunk(states[name], args.updates)
            jax.block_until_ready(states[name])
            rate = args.updates * steps_per_update / (time.perf_counter() - start)
            best[name] = max(best.get(name, 0.0), rate)
    print(f"{args.env} PPO ({steps_per_update} steps per update, {jax.default_backend()}, memory {args.memory_size}):")
    for name, rate in best.items():
        print(f"  {name:5s} {rate:10,.0f} env steps/s  ({rate / best['mlp']:.2f} x MLP)")
    record = {
        "benchmark": "recurrent-ppo-speed",
        "env": args.env,
        "memory_size": args.memory_size,
        "steps_per_update": steps_per_update,
        "updates_per_chunk": args.updates,
        "repeats": args.repeats,
        "env_steps_per_s": {name: round(rate, 1) for name, rate in best.items()},
        "relative_to_mlp": {name: round(rate / best["mlp"], 3) for name, rate in best.items()},
        "machine": describe_machine(),
        "command": "python benchmarks/recurrent_ppo_speed.py " + " ".join(sys.argv[1:]),
    }
    out = RESULTS / f"recurrent-ppo-speed-{args.env}-m{args.memory_size}-{jax.default_backend()}.json"
    out.write_text(json.dumps(record, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
