"""What a curriculum costs per training update against ``dr`` (issue 25: at most 25% more wall time).

    python benchmarks/curriculum_overhead.py                    # racing, the paper preset's ACKTR on rays
    python benchmarks/curriculum_overhead.py --env racing --algo ppo --option observation=route

Every arm trains the same algorithm and config on G(z) of the same generator, one seed, from the
same initial state; after compiling, the arms' chunks of ``--updates`` updates are timed in turn,
``--rounds`` times (interleaved, so a busy machine slows every arm alike); the median chunk
gives seconds per update and per episode, and the fastest chunk (the least disturbed) its ratio to
``dr`` as well. Writes ``benchmarks/results/curriculum-overhead-<env>.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from curriculum import paper_defaults  # noqa: E402
from machine import QUICK_RUN, RESULTS, describe_machine, require_input  # noqa: E402
from worldagent.agents.algorithms import get_algorithm, training_config  # noqa: E402
from worldagent.agents.distributions import world_distribution  # noqa: E402
from worldagent.curricula import make_curriculum  # noqa: E402
from worldagent.curricula.scores import target_score  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.files import write_text  # noqa: E402


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="racing")
    parser.add_argument("--algo", default=None)
    parser.add_argument("--option", action="append", default=None)
    parser.add_argument("--generator", type=Path, default=None)
    parser.add_argument("--arms", nargs="+", default=["dr", "plr", "accel", "target"])
    parser.add_argument("--updates", type=int, default=20)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--warmup", type=int, default=50, help="updates before timing (the buffer fills; replay may begin)")
    args = parser.parse_args(argv)

    spec = registry.get(args.env)
    defaults = paper_defaults(spec)
    algo = args.algo or defaults["algo"]
    options = spec.parse_options(args.option) if args.option else spec.check_options(defaults["options"])
    config = training_config(spec, algo, episodes=10**9, options=options)
    generator_dir = require_input(args.generator or Path("runs/quick") / spec.name / "generator", f"{QUICK_RUN} --env {spec.name}")
    latents = world_distribution(spec, "vae", generator_dir=generator_dir)
    env, params = spec.make_env(options)
    settings = {"buffer_size": 256, "min_fill": 0.25}  # small, so that replay begins within the warm-up
    trainers, states = {}, {}
    for arm in args.arms:
        target = target_score(spec, spec.failure) if arm == "target" else None
        curriculum = make_curriculum(arm, latents, settings if arm != "dr" else {}, target)
        trainers[arm] = get_algorithm(algo).make_train(config, env, params, curriculum, spec.training_params)
        state, _ = trainers[arm].train_chunk(trainers[arm].init(jax.random.key(0)), args.warmup)
        states[arm] = jax.block_until_ready(trainers[arm].train_chunk(state, args.updates)[0])  # compiled at this size
    seconds = {arm: [] for arm in args.arms}
    episodes = {arm: [] for arm in args.arms}
    for _ in range(args.rounds):
        for arm in args.arms:
            before = int(states[arm].episodes)
            start = time.perf_counter()
            states[arm] = jax.block_until_ready(trainers[arm].train_chunk(states[arm], args.updates)[0])
            seconds[arm].append((time.perf_counter() - start) / args.updates)
            episodes[arm].append((int(states[arm].episodes) - before) / args.updates)
    per_update = {arm: float(np.median(s)) for arm, s in seconds.items()}
    per_episode = {arm: per_update[arm] / max(float(np.mean(episodes[arm])), 1e-9) for arm in args.arms}
    result = {
        "env": spec.name,
        "algorithm": algo,
        "options": options,
        "settings": settings,
        "updates_per_chunk": args.updates,
        "rounds": args.rounds,
        "seconds_per_update": per_update,
        "episodes_per_update": {arm: float(np.mean(e)) for arm, e in episodes.items()},
        "seconds_per_episode": per_episode,
        "ratio_to_dr_per_update": {arm: per_update[arm] / per_update["dr"] for arm in args.arms} if "dr" in per_update else {},
        "ratio_to_dr_fastest_chunk": {arm: min(seconds[arm]) / min(seconds["dr"]) for arm in args.arms} if "dr" in seconds else {},
        "all_seconds_per_update": seconds,
        "machine": describe_machine(),
        "load_average_after": [round(x, 2) for x in os.getloadavg()],  # (1, 5, 15 min): ~1 on quiet 2 cores
        "command": "python benchmarks/curriculum_overhead.py " + " ".join(sys.argv[1:] if argv is None else argv),
    }
    out = RESULTS / f"curriculum-overhead-{spec.name}.json"
    write_text(out, json.dumps(result, indent=1))
    print(json.dumps({k: result[k] for k in ("seconds_per_update", "ratio_to_dr_per_update", "ratio_to_dr_fastest_chunk")}, indent=1))
    return result


if __name__ == "__main__":
    main()
