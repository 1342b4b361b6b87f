"""How much does the tagger fight? Conflict of harvest's default agents against scarcity, window, beam and training length.

    python benchmarks/harvest_conflict_sweep.py                       # every setting below, seed 0, 2,000 episodes
    python benchmarks/harvest_conflict_sweep.py --only perolat_window --episodes 5000 --seeds 0 1

Each setting trains four independent DQNs (agent 0 may TAG, paper §6.2.2) with harvest's
default config (``algorithms.training_config``) on the paper's dataset of 10,000 procedural
maps, then plays them (epsilon-greedy at ``DQNConfig.act_epsilon``) on 100 held-out maps x 8.
The learning curve gives conflict by training length for free (its episodes are played at
the same epsilon once exploration has decayed). Rows go to
``benchmarks/results/harvest-conflict-sweep.json``, one per (setting, episodes, seed); a
setting already recorded is skipped, so a killed sweep resumes. The table is in ``docs/harvest.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import RESULTS, describe_machine  # noqa: E402
from train_harvest import EVAL_SEED, evaluate, summary  # noqa: E402
from worldagent.agents.algorithms import training_config  # noqa: E402
from worldagent.agents.distributions import WorldPool  # noqa: E402
from worldagent.agents.training import train  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.envs.harvest.maps import generate_maps, seeds_from  # noqa: E402

SPEC = registry.get("harvest")
OUT = RESULTS / "harvest-conflict-sweep.json"
SETTINGS = {  # name -> env options besides tagger=0
    "ours": {},
    "scarce_0.5": {"regrowth": 0.5},
    "scarce_0.25": {"regrowth": 0.25},
    "perolat_window": {"view_size": 21, "view_behind": 0},
    "beam_10": {"beam_length": 10},
    "perolat_window_beam_10": {"view_size": 21, "view_behind": 0, "beam_length": 10},
}
CURVE_POINTS = (500, 1000, 2000, 3000, 5000)


def curve_at(curve: dict, name: str, point: int) -> float | None:
    """The learning curve's ``name`` averaged over its last 10 rows up to training episode ``point``."""
    episodes, values = np.asarray(curve.get("episodes", [])), np.asarray(curve.get(name, []), float)
    upto = values[episodes <= point]
    return round(float(np.nanmean(upto[-10:])), 4) if len(upto) and episodes.max() >= point else None


def run(name: str, extra: dict, episodes: int, seed: int, pool, worlds) -> dict:
    options = SPEC.check_options({"tagger": (0,), **extra})
    env, params = SPEC.make_env(options)
    config = training_config(SPEC, "dqn", episodes=episodes)
    out = Path(f"/tmp/worldagent-sweep/{name}-{episodes}-{seed}")
    start = time.perf_counter()
    result = train(SPEC, "dqn", config, pool, out, seed=seed, options=options, progress=False, resume=True)
    wall = time.perf_counter() - start
    trained = summary(evaluate(jax.random.key(seed + 1), result.agent.policy, worlds, env, params, 8))
    by_length = {str(p): curve_at(result.curve, "conflict", p) for p in CURVE_POINTS if p <= episodes}
    return {
        "setting": name,
        "options": {k: list(v) if isinstance(v, tuple) else v for k, v in options.items()},
        "episodes": episodes,
        "seed": seed,
        "train_wall_s": round(wall, 1),
        "eval": trained,
        "training_curve_conflict_by_episode": by_length,
    }


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", nargs="*", default=list(SETTINGS), choices=list(SETTINGS))
    parser.add_argument("--episodes", type=int, default=2000)
    parser.add_argument("--seeds", type=int, nargs="*", default=[0])
    args = parser.parse_args(argv)
    record = json.loads(OUT.read_text()) if OUT.exists() else {"benchmark": "harvest-conflict-sweep", "rows": []}
    record["machine"] = describe_machine()
    done = {(r["setting"], r["episodes"], r["seed"]) for r in record["rows"]}
    pool = WorldPool.create(generate_maps(seeds_from(0, 10_000)))
    worlds = generate_maps(seeds_from(EVAL_SEED, 100))
    for name in args.only:
        for seed in args.seeds:
            if (name, args.episodes, seed) in done:
                continue
            row = run(name, SETTINGS[name], args.episodes, seed, pool, worlds)
            record["rows"].append(row)
            OUT.write_text(json.dumps(record, indent=1))
            e = row["eval"]
            print(
                f"{name} seed {seed} {args.episodes} ep: conflict {e['conflict']:.3f} equality {e['equality']:.3f} "
                f"group {e['group_reward']:.1f} returns {e['returns']} ({row['train_wall_s'] / 60:.1f} min); by length {row['training_curve_conflict_by_episode']}",
                flush=True,
            )


if __name__ == "__main__":
    main()
