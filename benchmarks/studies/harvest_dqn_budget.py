"""What harvest's DQN agents learn at the smaller budgets a 10-minute quick preset can afford.

    python benchmarks/studies/harvest_dqn_budget.py --seeds 0 1            # every budget below
    python benchmarks/studies/harvest_dqn_budget.py --only b128-e1000 --seeds 2

Each budget trains four independent DQNs (agent 0 may TAG, as ``reproduce``'s harvest agents) with
harvest's default config but for the budget's episodes, minibatch and exploration decay, on the quick
preset's dataset size (5,000 procedural maps) with its ``learning_starts`` (4,000), then plays them
(epsilon-greedy at ``DQNConfig.act_epsilon``) on 100 held-out maps x 8. A gradient update's cost grows
with the minibatch (measured: 5.1 ms per update of the four agents at 128, 3.0 ms at 64; an episode of 40
envs without updates 0.95 s), so halving the minibatch or the episodes are the two ways to halve the cost
of training. Rows go to ``benchmarks/results/harvest-dqn-budget.json``, one per (budget, seed); a budget
already recorded is skipped, so a killed sweep resumes.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import jax

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: machine and the scripts imported
from machine import RESULTS, describe_machine  # noqa: E402
from train_harvest import EVAL_SEED, evaluate, summary  # noqa: E402
from worldagent.agents.algorithms import training_config  # noqa: E402
from worldagent.agents.distributions import WorldPool  # noqa: E402
from worldagent.agents.training import train  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.envs.harvest.maps import MapConfig, generate_maps, seeds_from  # noqa: E402

SPEC = registry.get("harvest")
OUT = RESULTS / "harvest-dqn-budget.json"
POOL, LEARNING_STARTS = 5_000, 4_000  # the quick preset's dataset and learning_starts
BUDGETS = {  # name -> (episodes, minibatch, episodes over which epsilon decays)
    "b128-e1000": (1000, 128, 1000),  # the quick preset before this study
    "b64-e1000": (1000, 64, 1000),
    "b128-e600": (600, 128, 600),
    "b64-e600": (600, 64, 600),
}


def run(name: str, seed: int) -> dict:
    episodes, batch, decay = BUDGETS[name]
    pool, worlds = WorldPool.create(generate_maps(seeds_from(0, POOL), MapConfig())), generate_maps(seeds_from(EVAL_SEED, 100), MapConfig())
    options = SPEC.check_options({"tagger": (0,)})
    env, params = SPEC.make_env(options)
    config = training_config(SPEC, "dqn", episodes=episodes).replace(batch_size=batch, epsilon_decay_episodes=decay, learning_starts=LEARNING_STARTS)
    out = Path(tempfile.gettempdir()) / "worldagent-dqn-budget" / f"{name}-{seed}"
    start, cpu = time.perf_counter(), time.process_time()
    result = train(SPEC, "dqn", config, pool, out, seed=seed, options=options, progress=False, resume=True)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    trained = summary(evaluate(jax.random.key(seed + 1), result.agent.policy, worlds, env, params, 8))
    return {"budget": name, "episodes": episodes, "batch_size": batch, "epsilon_decay_episodes": decay, "seed": seed,
            "train_wall_s": round(wall, 1), "train_cpu_s": round(cpu, 1), "eval": trained}  # fmt: skip


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", nargs="*", default=list(BUDGETS), choices=list(BUDGETS))
    parser.add_argument("--seeds", type=int, nargs="*", default=[0])
    args = parser.parse_args(argv)
    record = json.loads(OUT.read_text()) if OUT.exists() else {"benchmark": "harvest-dqn-budget", "rows": []}
    for name in args.only:
        for seed in args.seeds:
            record = json.loads(OUT.read_text()) if OUT.exists() else record  # another seed's process may have written
            if any((r["budget"], r["seed"]) == (name, seed) for r in record["rows"]):
                continue
            row = run(name, seed)
            record = json.loads(OUT.read_text()) if OUT.exists() else record
            record["machine"] = describe_machine()
            record["rows"].append(row)
            OUT.write_text(json.dumps(record, indent=1))
            e = row["eval"]
            print(f"{name} seed {seed}: group {e['group_reward']:.1f} conflict {e['conflict']:.3f} equality {e['equality']:.3f} "
                  f"returns {e['returns']} ({row['train_cpu_s']:.0f} CPU-s)", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
