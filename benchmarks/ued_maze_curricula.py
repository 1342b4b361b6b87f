"""worldagent's curricula on jaxued's UED maze, beside jaxued's own PLR / ACCEL / DR (issue 42, item 5).

    python benchmarks/ued_maze_jaxued.py ...            # jaxued's side first: its budget sets ours
    worldagent generator train ued_maze --out runs/ued-maze/generator
    python benchmarks/ued_maze_curricula.py --generator runs/ued-maze/generator --seeds 0 1 2

Needs the example package (``pip install -e examples/ued_maze``). Every worldagent arm trains PPO
with jaxued's ``maze_plr.py`` settings (32 envs x 256 steps per update, 5 epochs of one minibatch,
lr 1e-4 annealed, gamma 0.995, GAE 0.98, clip 0.2 on ratio and value, entropy 1e-3, a 256-unit LSTM
student) for exactly jaxued's env steps per run (``ued-maze-jaxued.json``), over latents z of the
run's own G(z):

- ``dr``: z ~ N(0, I);
- ``plr``: robust PLR (jaxued's default: no gradient from new worlds) with jaxued's buffer settings
  (4,000 worlds, replay 0.8, rank temperature 0.3, staleness 0.3, half full before replay); scores
  by positive value loss (jaxued's default score is MaxMC, which worldagent does not have);
- ``accel``: the same plus Gaussian edits of replayed latents (jaxued edits 5 maze cells);
- ``target``: replay ranked toward unsolved worlds (``solved < 0.5``);
- ``mlp``: ``dr`` with a memoryless MLP student (the recurrent-vs-MLP question of item 4).

Each agent then plays the held-out prefab mazes 10 times each (the papers' protocol; jaxued's
``--eval_levels``), ``--fresh`` mazes of jaxued's DR distribution (its generator with 25 wall
draws, what jaxued's ``dr`` trains on) and ``--fresh`` fresh procedural mazes of the example's
(0..25 wall draws; seeds none trained on) ``--repeats`` times each: on the latter their mean solve rate, α-CVaR at 10% (mean return of the worst 10% of mazes) and
P(failure) = P(solved < 0.5) with its exact interval. Across seeds: means with 95% Student-t
intervals for both implementations, whether each of ours lies within jaxued's seed spread, and
``pooled_vs_dr`` (paired by world over all seeds, hierarchical bootstrap). Writes
``benchmarks/results/ued-maze.json``; every trained agent and evaluation is cached under ``--work``,
so a killed run resumes.
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
from curriculum import agent_statistics, pooled_vs_dr, world_values  # noqa: E402
from machine import RESULTS, describe_machine, require_input  # noqa: E402
from worldagent import experiments  # noqa: E402
from worldagent.agents.algorithms import training_config  # noqa: E402
from worldagent.agents.distributions import world_distribution  # noqa: E402
from worldagent.agents.many import ManyRun, train_many  # noqa: E402
from worldagent.agents.training import CURVE_FILE, read_curve  # noqa: E402
from worldagent.curricula import label, make_curriculum  # noqa: E402
from worldagent.curricula.scores import target_score  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.evaluation.local import evaluate  # noqa: E402
from worldagent.files import write_text  # noqa: E402
from worldagent.influence.statistics import mean_and_ci  # noqa: E402

ENV = "ued_maze"
PREFAB_ATTEMPTS = 10  # jaxued's --eval_num_attempts
FRESH_SEED = 900_000_000  # fresh procedural mazes: far from every dataset seed (0..9,999)
EVAL_KEY = 20_261_128
JAXUED_PPO = {  # maze_plr.py's defaults, in PPOConfig's names
    "num_envs": 32,
    "num_steps": 256,
    "update_epochs": 5,
    "num_minibatches": 1,
    "learning_rate": 1e-4,
    "anneal_lr": True,
    "gamma": 0.995,
    "gae_lambda": 0.98,
    "clip_eps": 0.2,
    "clip_value": True,
    "ent_coef": 1e-3,
    "vf_coef": 0.5,
    "max_grad_norm": 0.5,
    "recurrent": "lstm",
    "memory_size": 256,
    "hidden": (144,),  # jaxued's conv embedding of the 5x5 view is 3x3x16 = 144 features
    "activation": "relu",
}
JAXUED_PLR = {"buffer_size": 4000, "replay_prob": 0.8, "temperature": 0.3, "staleness": 0.3, "min_fill": 0.5, "robust": True}
ARMS = {  # arm: (curriculum, its settings, PPO overrides)
    "dr": ("dr", {}, {}),
    "plr": ("plr", JAXUED_PLR, {}),
    "accel": ("accel", JAXUED_PLR, {}),
    "target": ("target", {"replay_prob": 0.8}, {}),
    "mlp": ("dr", {}, {"recurrent": None, "hidden": (128, 128), "activation": "tanh"}),
}
JAXUED_ARMS = ("dr", "plr", "accel")


def jaxued_dr_mazes(count: int):
    """``count`` mazes from jaxued's DR distribution: its generator with its fixed 25 wall draws (ours draws 0..25)."""
    from jaxued.environments.maze import make_level_generator
    from ued_maze.world import MAX_WALLS, SIZE, from_level

    keys = jax.random.split(jax.random.key(FRESH_SEED), count)
    return jax.vmap(lambda key: from_level(make_level_generator(SIZE, SIZE, MAX_WALLS)(key)))(keys)


def jaxued_side(path: Path) -> dict:
    """jaxued's runs (``ued_maze_jaxued.py``): {arm: {seed: mean prefab solve rate}}, per-level rates, the budget."""
    record = json.loads(path.read_text())
    per_seed: dict = {}
    for run in record["runs"]:
        per_seed.setdefault(run["arm"], {})[run["seed"]] = {"prefab_solve_rate": run["mean_solve_rate"], "per_prefab": run["solve_rates"]}
    return {"per_seed": per_seed, "env_steps_per_run": int(record["env_steps_per_run"]), "file": str(path)}


def train_arm(spec, config, curriculum, seeds, work: Path, progress: bool) -> list[str]:
    """The arm's agents (its seeds as one vmapped program; a finished one is read back, a killed one resumes)."""
    runs = [ManyRun(work / f"s{seed}", seed=seed, distribution=curriculum, distribution_spec=label(curriculum)) for seed in seeds]
    pending = [run for run in runs if not (run.out_dir / "policy" / "policy.json").is_file()]  # added seeds train alone
    if pending:
        train_many(spec, "ppo", config, pending, progress=progress)
    return [str(run.out_dir) for run in runs]


def played(spec, agent_dir: str, generator, worlds, repeats: int, cache: Path) -> dict[str, np.ndarray]:
    """{metric: f64[B, R]} of the agent on ``worlds``, cached in ``cache``."""
    if cache.is_file():
        return dict(np.load(cache))
    setup = experiments.setup(spec.name, agent_dir, generator, repeats=repeats)
    metrics = evaluate(setup.env, setup.policy, worlds, repeats, jax.random.key(EVAL_KEY), setup.params)
    metrics = {name: np.asarray(value, np.float64) for name, value in metrics.items()}
    cache.parent.mkdir(parents=True, exist_ok=True)
    with open(cache, "wb") as handle:
        np.savez(handle, **metrics)
    return metrics


def training_record(agent_dir: str) -> dict:
    """Env steps, episodes and wall seconds of a finished run, from its curve."""
    last = read_curve(Path(agent_dir) / CURVE_FILE)[-1]
    return {name: float(last[name]) for name in ("env_steps", "episodes", "wall_seconds") if name in last}


def summary(per_seed: dict[str, dict], stat: str) -> dict:
    """{arm: mean ± 95% t interval over seeds of ``stat``, with the per-seed values}."""
    out = {}
    for arm, seeds in per_seed.items():
        values = [row[stat] for row in seeds.values() if stat in row]
        if values:
            out[arm] = {**mean_and_ci(np.array(values, np.float64)), "values": values}
    return out


def within_spread(ours: dict, theirs: dict) -> dict:
    """For each arm both sides have: does our seed mean lie within [min, max] of jaxued's seeds, or above?"""
    out = {}
    for arm in set(ours) & set(theirs):
        low, high = min(theirs[arm]["values"]), max(theirs[arm]["values"])
        mean = ours[arm]["mean"]
        out[arm] = {"jaxued_range": [low, high], "ours_mean": mean, "within_or_better": bool(mean >= low)}
    return out


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--generator", type=Path, default=Path("runs/ued-maze/generator"))
    parser.add_argument("--jaxued", type=Path, default=RESULTS / "ued-maze-jaxued.json", help="jaxued's side (ued_maze_jaxued.py)")
    parser.add_argument("--env-steps", type=int, default=None, help="env steps per run (default: jaxued's)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--arms", nargs="+", default=list(ARMS), choices=list(ARMS))
    parser.add_argument("--fresh", type=int, default=500, help="fresh procedural mazes each agent plays")
    parser.add_argument("--repeats", type=int, default=4, help="episodes per fresh maze")
    parser.add_argument("--work", type=Path, default=Path("runs/ued-maze"))
    parser.add_argument("--out", type=Path, default=RESULTS / "ued-maze.json")
    parser.add_argument("--note", action="append", default=[])
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)

    spec = registry.get(ENV)
    jaxued = jaxued_side(args.jaxued) if args.jaxued.is_file() else {"per_seed": {}, "env_steps_per_run": None}
    env_steps = args.env_steps or jaxued["env_steps_per_run"]
    if not env_steps:
        raise SystemExit(f"no budget: run benchmarks/ued_maze_jaxued.py first (it writes {args.jaxued}) or pass --env-steps.")
    generator_dir = require_input(args.generator, f"pip install -e examples/ued_maze && worldagent generator train ued_maze --out {args.generator}")
    latents = world_distribution(spec, "vae", generator_dir=generator_dir)
    generator = latents.generator
    _, params = spec.make_env({})
    prefabs = spec.world_sets["prefabs"]()
    fresh = spec.generate(np.arange(FRESH_SEED, FRESH_SEED + args.fresh))
    dr25 = jaxued_dr_mazes(args.fresh)
    names = list(__import__("ued_maze").PREFAB_NAMES)

    per_seed: dict = {}
    values: dict = {}
    configs: dict = {}
    for arm in args.arms:
        name, settings, overrides = ARMS[arm]
        config = training_config(spec, "ppo", episodes=10**9, **{**JAXUED_PPO, **overrides, "total_env_steps": env_steps})
        configs[arm] = config.to_dict()
        target = target_score(spec, spec.failure, None) if name == "target" else None
        curriculum = make_curriculum(name, latents, settings, target)
        clock = time.perf_counter()
        dirs = train_arm(spec, config, curriculum, args.seeds, args.work / arm, not args.quiet)
        print(f"{arm}: trained in {time.perf_counter() - clock:.0f} s", flush=True)
        per_seed[arm] = {}
        for seed, agent_dir in zip(args.seeds, dirs):
            on_prefabs = played(spec, agent_dir, generator, prefabs, PREFAB_ATTEMPTS, args.work / "eval" / f"{arm}-s{seed}-prefabs.npz")
            on_fresh = played(spec, agent_dir, generator, fresh, args.repeats, args.work / "eval" / f"{arm}-s{seed}-fresh{args.fresh}.npz")
            on_dr25 = played(spec, agent_dir, generator, dr25, args.repeats, args.work / "eval" / f"{arm}-s{seed}-jaxued-dr{args.fresh}.npz")
            rates = on_prefabs["solved"].mean(axis=1)
            stats = agent_statistics(spec, on_fresh, params)
            per_seed[arm][seed] = {
                "prefab_solve_rate": float(rates.mean()),
                "per_prefab": dict(zip(names, map(float, rates))),
                "fresh_solve_rate": float(on_fresh["solved"].mean()),
                "jaxued_dr_solve_rate": float(on_dr25["solved"].mean()),
                **{f"fresh_{key}": value for key, value in stats.items() if key in ("cvar10", "p_failure", "p_failure_interval", "worst")},
                "training": training_record(agent_dir),
            }
            values.setdefault(arm, []).append(world_values(spec, on_fresh, params))
            print(arm, seed, {k: v for k, v in per_seed[arm][seed].items() if k != "per_prefab"}, flush=True)
        ours = summary(per_seed, "prefab_solve_rate")
        theirs = summary(jaxued["per_seed"], "prefab_solve_rate")
        result = {
            "benchmark": "ued-maze",
            "env_steps_per_run": env_steps,
            "seeds": args.seeds,
            "generator": str(args.generator),
            "repair": generator.repair_name,
            "prefabs": names,
            "prefab_attempts": PREFAB_ATTEMPTS,
            "fresh": {"mazes": args.fresh, "repeats": args.repeats, "first_seed": FRESH_SEED, "failure": spec.failure},
            "jaxued_dr_mazes": {"mazes": args.fresh, "repeats": args.repeats, "key": FRESH_SEED, "walls": "25 draws, jaxued's DR"},
            "worldagent": {
                "configs": configs,
                "curriculum_settings": {arm: ARMS[arm][1] for arm in per_seed},
                "per_seed": per_seed,
                "prefab_solve_rate": ours,
                "fresh_solve_rate": summary(per_seed, "fresh_solve_rate"),
                "jaxued_dr_solve_rate": summary(per_seed, "jaxued_dr_solve_rate"),
                "fresh_cvar10": summary(per_seed, "fresh_cvar10"),
                "fresh_p_failure": summary(per_seed, "fresh_p_failure"),
                "pooled_vs_dr": pooled_vs_dr(values),
            },
            "jaxued": {**jaxued, "prefab_solve_rate": theirs},
            "ours_within_jaxued_spread": within_spread(ours, {a: theirs[a] for a in JAXUED_ARMS if a in theirs}),
            "notes": args.note,
            "machine": describe_machine(),
            "command": "python benchmarks/ued_maze_curricula.py " + " ".join(sys.argv[1:] if argv is None else argv),
        }
        write_text(args.out, json.dumps(result, indent=1, default=float))
    return result


if __name__ == "__main__":
    main()
