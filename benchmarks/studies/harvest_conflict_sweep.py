"""How much does the tagger fight? Conflict of harvest's default agents against scarcity, window, beam and training length.

    python benchmarks/studies/harvest_conflict_sweep.py                       # every setting below, seed 0, 2,000 episodes
    python benchmarks/studies/harvest_conflict_sweep.py --only perolat_window --episodes 5000 --seeds 0 1

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
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: machine and the scripts imported
from machine import RESULTS, describe_machine  # noqa: E402
from train_harvest import EVAL_SEED, evaluate, summary  # noqa: E402
from worldagent.agents.algorithms import training_config  # noqa: E402
from worldagent.agents.distributions import WorldPool  # noqa: E402
from worldagent.agents.training import train  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.envs.harvest.maps import MapConfig, generate_maps, seeds_from  # noqa: E402
from worldagent.envs.harvest.world import DEFAULT_SIZE  # noqa: E402

SPEC = registry.get("harvest")
OUT = RESULTS / "harvest-conflict-sweep.json"
SETTINGS = {  # name -> env options besides tagger=0, and "map_size" (the procedural maps' side)
    "map_25": {"map_size": 25},
    "map_19": {"map_size": 19},
    "map_15": {"map_size": 15},
    "map_25_scarce_0.5": {"map_size": 25, "regrowth": 0.5},
    "map_25_scarce_0.25": {"map_size": 25, "regrowth": 0.25},
    "map_25_perolat_window": {"map_size": 25, "view_size": 21, "view_behind": 0},
    "map_25_beam_10": {"map_size": 25, "beam_length": 10},
    "map_19_beam_10": {"map_size": 19, "beam_length": 10},
    "map_19_scarce_0.5": {"map_size": 19, "regrowth": 0.5},
}
CURVE_POINTS = (500, 1000, 2000, 3000, 5000)


def curve_at(curve: dict, name: str, point: int) -> float | None:
    """The learning curve's ``name`` averaged over its last 10 rows up to training episode ``point``."""
    episodes, values = np.asarray(curve.get("episodes", [])), np.asarray(curve.get(name, []), float)
    upto = values[episodes <= point]
    return round(float(np.nanmean(upto[-10:])), 4) if len(upto) and episodes.max() >= point else None


def maps(extra: dict, first_seed: int, count: int):
    return generate_maps(seeds_from(first_seed, count), MapConfig(size=extra.get("map_size", DEFAULT_SIZE)))


def run(name: str, extra: dict, episodes: int, seed: int) -> dict:
    pool, worlds = WorldPool.create(maps(extra, 0, 10_000)), maps(extra, EVAL_SEED, 100)
    options = SPEC.check_options({"tagger": (0,), **{k: v for k, v in extra.items() if k != "map_size"}})
    env, params = SPEC.make_env(options)
    config = training_config(SPEC, "dqn", episodes=episodes)
    out = Path(tempfile.gettempdir()) / "worldagent-sweep" / f"{name}-{episodes}-{seed}"
    start = time.perf_counter()
    result = train(SPEC, "dqn", config, pool, out, seed=seed, options=options, progress=False, resume=True)
    wall = time.perf_counter() - start
    trained = summary(evaluate(jax.random.key(seed + 1), result.agent.policy, worlds, env, params, 8))
    by_length = {str(p): curve_at(result.curve, "conflict", p) for p in CURVE_POINTS if p <= episodes}
    return {
        "setting": name,
        "options": {k: list(v) if isinstance(v, tuple) else v for k, v in options.items()},
        "map_size": extra.get("map_size", DEFAULT_SIZE),
        "episodes": episodes,
        "seed": seed,
        "train_wall_s": round(wall, 1),
        "eval": trained,
        "training_curve_conflict_by_episode": by_length,
    }


def table(rows: list[dict]) -> str:
    """The sweep as a markdown table (the one in docs/harvest.md)."""
    lines = [
        "| setting | map | window (behind) | beam | regrowth | episodes | seed | conflict | equality | group reward | returns (agent 0 tags) | conflict in training at 500 / 1,000 / 2,000 / 5,000 episodes |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        o, e, c = r["options"], r["eval"], r["training_curve_conflict_by_episode"]
        by_length = " / ".join("–" if c.get(p) is None else f"{c[p]:.3f}" for p in ("500", "1000", "2000", "5000"))
        lines.append(
            f"| {r['setting']} | {r['map_size']} | {o['view_size']} ({o['view_behind']}) | {o['beam_length']} | {o['regrowth']} | "
            f"{r['episodes']} | {r['seed']} | {e['conflict']:.3f} | {e['equality']:.3f} | {e['group_reward']:.1f} | {e['returns']} | {by_length} |"
        )
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", nargs="*", default=list(SETTINGS), choices=list(SETTINGS))
    parser.add_argument("--episodes", type=int, default=2000)
    parser.add_argument("--seeds", type=int, nargs="*", default=[0])
    parser.add_argument("--table", action="store_true", help="print the recorded sweep as a markdown table and exit")
    args = parser.parse_args(argv)
    record = json.loads(OUT.read_text()) if OUT.exists() else {"benchmark": "harvest-conflict-sweep", "rows": []}
    if args.table:
        print(table(record["rows"]))
        return
    record["machine"] = describe_machine()
    done = {(r["setting"], r["episodes"], r["seed"]) for r in record["rows"]}
    for name in args.only:
        for seed in args.seeds:
            if (name, args.episodes, seed) in done:
                continue
            row = run(name, SETTINGS[name], args.episodes, seed)
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
