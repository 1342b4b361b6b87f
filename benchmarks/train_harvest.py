"""Time the harvest agents' training (paper §5.3) and measure them against random agents.

    python benchmarks/train_harvest.py                         # the paper's 5,000 episodes, agent 0 tags (§6.2.2)
    python benchmarks/train_harvest.py --tagger none           # nobody tags
    python benchmarks/train_harvest.py --episodes 800          # a shorter run (the time is extrapolated)
    python benchmarks/train_harvest.py --seeds 0 1 2 3 4 --together   # 5 seeds as one program (many.train_many)

Trains four independent DQNs (``worldagent.agents.dqn``, harvest's default config from
``algorithms.training_config``) through the host driver ``training.train`` on a uniform
pool of procedurally generated maps (seeds 0..pool-1), then plays the trained agents
(epsilon-greedy with ``DQNConfig.act_epsilon``; also greedy and at 0.05 and 0.1) and
uniformly random agents on the same held-out maps (seeds from 1,000,000), ``--repeats``
episodes each (the paper evaluates each world 8 times, §5.2.2) with the same keys. Reports the
wall time of training (compilation included: it is part of what a user waits for), env-steps
and agent-steps per second, the group-reward ratio trained / random, and equality and conflict
(the paper's default agents with agent 0 tagging: conflict 0.51, equality 0.33, §6.2.2). When
``--episodes`` is below the paper's 5,000 the full-budget time is extrapolated from the measured
rate and labelled so. Results go to ``benchmarks/results/train_harvest-<tagger>-<backend>.json``
with the machine's description; the run directory (curve, checkpoint, policy) to ``--out``.

``--seeds`` trains several agents (one after another, or with ``--together`` as one vmapped
program, ``many.train_many``, at most ``--max-together`` per program), each in ``--out``/seed<N>;
the training time is that of all of them, the evaluation above is the first seed's, and every
seed's metrics are in ``per_seed``. Results then go to ``train_harvest-<tagger>-<N>seeds[-together]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import describe_machine, record  # noqa: E402
from worldagent.agents.algorithms import training_config  # noqa: E402
from worldagent.agents.distributions import WorldPool  # noqa: E402
from worldagent.agents.dqn import DQNConfig  # noqa: E402
from worldagent.agents.loaders import load_agent  # noqa: E402
from worldagent.agents.many import ManyRun, train_many  # noqa: E402
from worldagent.agents.policy import network_policy  # noqa: E402
from worldagent.agents.training import train  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.envs.core import rollout  # noqa: E402
from worldagent.envs.harvest.maps import generate_maps, seeds_from  # noqa: E402

PAPER_EPISODES = 5000
TARGET_MINUTES = 60
EVAL_SEED = 1_000_000


SPEC = registry.get("harvest")


def evaluate(key, policy, worlds, env, params, repeats: int) -> dict:
    """``env.metrics`` of ``policy``'s episodes on each world: f[B, repeats] (``returns`` f[B, repeats, 4])."""

    def one(world, k):
        return env.metrics(rollout(env, policy, k, world, params, int(params.max_steps))[0])

    n = jax.tree_util.tree_leaves(worlds)[0].shape[0]
    keys = jax.random.split(key, (n, repeats))
    return jax.jit(jax.vmap(lambda w, ks: jax.vmap(lambda k: one(w, k))(ks)))(worlds, keys)


def summary(metrics: dict) -> dict:
    """Means over worlds and repeats of the scalar metrics, and per-agent mean returns."""
    out = {name: round(float(np.mean(value)), 4) for name, value in metrics.items() if name != "returns"}
    out["returns"] = [round(float(r), 2) for r in np.asarray(metrics["returns"]).mean(axis=(0, 1))]
    return out


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=PAPER_EPISODES, help="training episodes per agent (paper: 5000)")
    parser.add_argument("--tagger", default="0", help="agents allowed to TAG (e.g. 0 or 0,2), or 'none' (paper §6.2.2: 0)")
    parser.add_argument("--num-envs", type=int, default=DQNConfig.num_envs)
    parser.add_argument("--pool", type=int, default=10_000, help="training maps (the paper's dataset: 10,000)")
    parser.add_argument("--eval-worlds", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--seeds", type=int, nargs="+", default=None, help="several training seeds (default: --seed)")
    parser.add_argument("--together", action="store_true", help="train the seeds as one vmapped program (many.train_many)")
    parser.add_argument("--max-together", type=int, default=None, help="with --together: seeds per program at most (default: from the device)")
    parser.add_argument("--out", type=Path, default=None, help="run directory (default: a fresh one under /tmp)")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)

    options = SPEC.parse_options([f"tagger={args.tagger}"])
    config = training_config(SPEC, "dqn", episodes=args.episodes, num_envs=args.num_envs)
    name = f"tagger{','.join(map(str, options['tagger']))}" if options["tagger"] else "notag"
    out = args.out or Path(f"/tmp/worldagent-train-harvest-{name}-{int(time.time())}")
    pool = WorldPool.create(generate_maps(seeds_from(0, args.pool)))
    env, params = SPEC.make_env(options)

    seeds = args.seeds or [args.seed]
    several = len(seeds) > 1 or args.together
    if several:
        name += f"-{len(seeds)}seeds" + ("-together" if args.together else "")
    out_dir = lambda seed: out / f"seed{seed}" if several else out  # noqa: E731
    start = time.perf_counter()
    if args.together:
        runs = [ManyRun(out_dir(seed), seed=seed, distribution=pool) for seed in seeds]
        results = train_many(SPEC, "dqn", config, runs, options=options, progress=not args.quiet, resume=False, max_together=args.max_together)
    else:
        results = [
            train(SPEC, "dqn", config, pool, out_dir(seed), seed=seed, options=options, progress=not args.quiet, resume=False) for seed in seeds
        ]
    wall = time.perf_counter() - start
    result = results[0]
    env_steps = sum(r.env_steps for r in results)
    env_steps_per_s = env_steps / wall
    full_budget_s = len(seeds) * PAPER_EPISODES * int(params.max_steps) / env_steps_per_s

    worlds = generate_maps(seeds_from(EVAL_SEED, args.eval_worlds))
    key = jax.random.key(args.seed + 1)
    agent = result.agent
    trained = summary(evaluate(key, agent.policy, worlds, env, params, args.repeats))
    by_epsilon = {
        str(eps): summary(
            evaluate(key, network_policy(agent.module, agent.params, "q_network", num_agents=4, epsilon=eps), worlds, env, params, args.repeats)
        )
        for eps in (0.0, 0.05, 0.1)
        if eps != config.act_epsilon
    }
    random = summary(evaluate(key, load_agent(SPEC, "random", options=options), worlds, env, params, args.repeats))
    per_seed = [
        {"seed": seed, "episodes": r.episodes, "trained": summary(evaluate(key, r.agent.policy, worlds, env, params, args.repeats))}
        for seed, r in zip(seeds, results)
    ]
    figures = {
        "command": "python benchmarks/train_harvest.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "options": {k: list(v) if isinstance(v, tuple) else v for k, v in options.items()},
        "config": config.to_dict(),
        "seeds": seeds,
        "training": f"many.train_many, {len(seeds)} seeds as one program (max {args.max_together or 'from the device'})"
        if args.together
        else "training.train, one seed after another",
        "episodes_trained": result.episodes,
        "env_steps": env_steps,
        "agent_steps": 4 * env_steps,
        "train_wall_s": round(wall, 1),
        "env_steps_per_s": round(env_steps_per_s),
        "agent_steps_per_s": round(4 * env_steps_per_s),
        "paper_budget_wall_min": round(full_budget_s / 60, 1),
        "paper_budget_wall_is": ("measured" if result.episodes >= PAPER_EPISODES else "extrapolated from the measured rate")
        + f", all {len(seeds)} seeds",
        "target_min": TARGET_MINUTES,
        "eval": {
            "worlds": args.eval_worlds,
            "repeats": args.repeats,
            "first_seed": EVAL_SEED,
            "policy": f"epsilon-greedy, act_epsilon {config.act_epsilon}",
        },
        "trained": trained,
        "random": random,
        "trained_at_other_epsilon": by_epsilon,
        "group_reward_ratio": round(trained["group_reward"] / max(random["group_reward"], 1e-9), 2),
        "paper_default_agents_tagging": {"conflict": 0.51, "equality": 0.33},
        "final_training_chunk": {k: float(v[-1]) for k, v in result.curve.items() if len(v)},
        **({"per_seed": per_seed} if len(seeds) > 1 else {}),
        "run_dir": str(out),
    }
    path = record(f"train_harvest-{name}", figures)
    machine = describe_machine()
    print(
        f"{figures['episodes_trained']} episodes in {wall / 60:.1f} min ({figures['env_steps_per_s']} env-steps/s, "
        f"{machine['cores']} cores); paper budget: {figures['paper_budget_wall_min']} min ({figures['paper_budget_wall_is']})\n"
        f"group reward trained {trained['group_reward']:.1f} vs random {random['group_reward']:.1f}: ratio {figures['group_reward_ratio']}\n"
        f"equality {trained['equality']:.3f}, conflict {trained['conflict']:.3f} (random: {random['equality']:.3f}, {random['conflict']:.3f})\n"
        f"recorded in {path}"
    )
    return figures


if __name__ == "__main__":
    main()
