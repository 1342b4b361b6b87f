"""Online curricula against plain random worlds, judged on the worst worlds (issue 25).

    python benchmarks/curriculum.py --env racing                       # ACKTR on rays, 5 seeds x 10,000 episodes
    python benchmarks/curriculum.py --env harvest --target conflict --minimize
    python benchmarks/curriculum.py --env racing --episodes 2000 --curriculum-set buffer_size=500 --work runs/curriculum-racing-2000

Every arm trains the same algorithm, config and episode budget on G(z) of the same generator;
only the curriculum differs (``dr``: z ~ N(0, I); ``plr``, ``accel``; ``target``: toward
``--target``, by default the env's failure event). The seeds of an arm train as one program
(``agents.many.train_many``). Every final agent then plays the same ``--eval-worlds`` fresh
worlds z ~ N(0, I) (their own seed) ``--repeats`` times, and we report per agent:

- ``mean``: the mean over worlds of the main metric (normalised to [0, 1] where the env has bounds);
- ``cvar10``: the α-CVaR at 10%, the mean over the worst 10% of those worlds (Rutherford et al. 2024);
- ``p_failure``: the share of worlds where the env's failure event holds (world means), with its
  exact (Clopper-Pearson) interval: Monte Carlo over the evaluation worlds;
- ``worst``: the worst world's main metric among them (a random search of ``--eval-worlds``;
  a fixed-budget atlas per agent was not run);
- the training wall time of each arm (its seeds together, from the runs' curves: resumes add up).

Across seeds: means with 95% Student-t intervals, and whether each arm's interval overlaps
``dr``'s. Every step is cached under ``--work``: a killed run resumes. Writes
``benchmarks/results/curriculum-<env>.json``.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import RESULTS, describe_machine  # noqa: E402
from worldagent import experiments  # noqa: E402
from worldagent.agents.algorithms import training_config  # noqa: E402
from worldagent.agents.distributions import world_distribution  # noqa: E402
from worldagent.agents.many import ManyRun, train_many  # noqa: E402
from worldagent.analysis.intervals import clopper_pearson  # noqa: E402
from worldagent.curricula import label, make_curriculum, parse_curriculum_settings  # noqa: E402
from worldagent.curricula.scores import target_score  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.evaluation.local import evaluate  # noqa: E402
from worldagent.events import parse_selection  # noqa: E402
from worldagent.files import write_text  # noqa: E402
from worldagent.influence.experiment import compared_metrics  # noqa: E402
from worldagent.influence.statistics import mean_and_ci  # noqa: E402
from worldagent.search.objectives import generate  # noqa: E402

EVAL_SEED = 20_251_126  # the evaluation worlds' own stream, apart from every training seed
ALPHA = 0.10
STATS = ("mean", "cvar10", "p_failure", "worst")
SECONDS_KEY = "_evaluation_seconds"  # kept in each agent's evaluation cache beside its metrics
NOT_RUN = {
    "rounds arm": "`influence --rounds 3` is not an arm yet",
    "atlas worst world": "the worst world is the worst of the evaluation worlds (a random search), not a fixed-budget atlas per agent",
}


def paper_defaults(spec) -> dict:
    """The paper preset's algorithm, options and episode budget for ``spec`` (what ``--preset paper`` trains)."""
    budgets = spec.presets.get("paper", {})
    return {
        "algo": budgets.get("algo") or spec.default_algorithm,
        "options": dict(budgets.get("options") or spec.reproduce_options or {}),
        "episodes": int(budgets.get("episodes", 1000)),
    }


def trained_before(out_dir: Path, config, described: str) -> dict | None:
    """{episodes, wall_seconds} of a run this benchmark trained to its budget before, read from its
    run.json, saved agent and curve, not its checkpoint (which a later change to the env's state
    would no longer restore); None when it is not finished or was trained otherwise."""
    files = {name: out_dir / name for name in ("run.json", "curve.csv", "policy/policy.json")}
    if not all(path.is_file() for path in files.values()):
        return None
    record = json.loads(files["run.json"].read_text())
    if record.get("config") != json.loads(json.dumps(config.to_dict())) or record.get("distribution") != described:
        return None
    with open(files["curve.csv"], newline="") as handle:
        last = list(csv.DictReader(handle))[-1]
    episodes = int(float(last["episodes"]))
    return {"episodes": episodes, "wall_seconds": float(last["wall_seconds"])} if episodes >= config.episodes else None


def train_arm(spec, algo, config, options, curriculum, seeds, work: Path, progress: bool) -> dict:
    """Train one arm's seeds as one program (resumable); its agents' directories, episodes and wall seconds."""
    described = label(curriculum)
    runs = [ManyRun(work / f"s{seed}", seed=seed, distribution=curriculum, distribution_spec=described) for seed in seeds]
    done = [trained_before(run.out_dir, config, described) for run in runs]
    if all(done):
        return {
            "dirs": [str(run.out_dir) for run in runs],
            "wall_seconds": max(d["wall_seconds"] for d in done),
            "episodes": [d["episodes"] for d in done],
        }
    results = train_many(spec, algo, config, runs, options=options, progress=progress)
    wall = max(float(r.curve["wall_seconds"][-1]) for r in results)  # the curves' clock: the whole training across resumes
    return {"dirs": [str(r.out_dir) for r in results], "wall_seconds": round(wall, 1), "episodes": [r.episodes for r in results]}


def offline_arm(
    spec, algo, config, options, generator, generator_dir: Path, policy_dir: str, seeds, work: Path, counts: dict, progress: bool
) -> dict:
    """The paper's influence (§6.2), offline: the first seed's ``dr`` agent plays ``counts["candidates"]``
    random worlds and a CMA-ES search of ``counts["search_budget"]`` more (8 episodes each); the worlds
    with the env's selection become the pool every seed's agent trains on from scratch."""
    from worldagent.agents.distributions import WorldPool
    from worldagent.influence.experiment import find_worlds
    from worldagent.influence.worlds import resolved
    from worldagent.store import RunStore

    selection = resolved(spec.selection, spec)
    setup = experiments.setup(spec.name, policy_dir, str(generator_dir), repeats=counts["repeats"])
    work.mkdir(parents=True, exist_ok=True)
    clock = time.perf_counter()
    with RunStore(work) as store:
        tried, _, worlds, latents, _, _ = find_worlds(store, spec, setup.env, setup.params, setup.policy, generator, selection, counts, progress)
    search_wall = time.perf_counter() - clock
    if len(latents) == 0:  # nothing to retrain on: said, and the other arms go on
        return {
            "not_run": f"none of the {len(tried)} worlds the s{seeds[0]} dr agent played has {selection.describe()}",
            "search_wall_seconds": round(search_wall, 1),
        }
    trained = train_arm(spec, algo, config, options, WorldPool.create(worlds), seeds, work, progress)
    return {
        **trained,
        "curriculum": f"pool of {len(latents)} worlds with {selection.describe()} (of {len(tried)} tried by the s{seeds[0]} dr agent)",
        "search_wall_seconds": round(search_wall, 1),
        "search_episodes": len(tried) * counts["repeats"],
        "training_episodes_before": "the selecting dr agent's training (the dr arm's first seed)",
    }


def evaluation_worlds(generator, count: int):
    z = jax.random.normal(jax.random.key(EVAL_SEED), (count, generator.latent_dim))
    return np.asarray(z), generate(generator, z)


def evaluate_agent(spec, agent_dir: str, generator_dir: Path, worlds, repeats: int, cache: Path) -> tuple[dict[str, np.ndarray], float | None]:
    """({metric: f64[B, R]} of the agent on the evaluation worlds, the seconds that took), cached
    (seconds None for a cache written before they were kept)."""
    if cache.is_file():
        stored = dict(np.load(cache))
        seconds = stored.pop(SECONDS_KEY, None)
        return stored, None if seconds is None else float(seconds)
    clock = time.perf_counter()
    setup = experiments.setup(spec.name, agent_dir, str(generator_dir), repeats=repeats)
    metrics = evaluate(setup.env, setup.policy, worlds, repeats, jax.random.key(EVAL_SEED + 1), setup.params)
    metrics = {name: np.asarray(value, np.float64) for name, value in spec.metrics.with_derived(metrics, setup.params).items()}
    seconds = time.perf_counter() - clock
    cache.parent.mkdir(parents=True, exist_ok=True)
    with open(cache, "wb") as handle:
        np.savez(handle, **metrics, **{SECONDS_KEY: np.float64(seconds)})
    return metrics, seconds


def agent_statistics(spec, metrics: dict[str, np.ndarray], params) -> dict:
    """mean, cvar10, p_failure (+ interval), worst of one agent (see module docstring)."""
    main = metrics[spec.metrics.main].mean(axis=1)
    score = spec.metrics.normalise(main, params) if spec.metrics.bounds is not None else main
    worst_first = np.sort(score)
    tail = max(1, int(np.ceil(ALPHA * len(score))))
    failing = np.ones(len(score), bool)
    for clause in parse_selection(spec.failure, spec.name).clauses:
        failing &= clause.holds(metrics[clause.metric].mean(axis=1))
    k, n = int(failing.sum()), len(failing)
    low, high = clopper_pearson(k, n)
    return {
        "mean": float(score.mean()),
        "cvar10": float(worst_first[:tail].mean()),
        "p_failure": k / n,
        "p_failure_interval": [low, high],
        "worst": float(worst_first[0]),
        "failing_worlds": k,
        **{f"mean_{name}": float(metrics[name].mean()) for name in compared_metrics(spec)},
    }


def compare(per_seed: dict[str, dict[int, dict]]) -> dict:
    """{stat: {arm: mean_and_ci over seeds, + overlaps_dr}}."""
    out: dict = {}
    first = next(iter(next(iter(per_seed.values())).values()))
    for stat in (*STATS, *(name for name in first if name.startswith("mean_"))):
        out[stat] = {arm: mean_and_ci([values[stat] for values in seeds.values()]) for arm, seeds in per_seed.items()}
        base = out[stat].get("dr")
        for arm, summary in out[stat].items():
            if base is not None and arm != "dr" and np.isfinite(summary["ci95"]) and np.isfinite(base["ci95"]):
                apart = abs(summary["mean"] - base["mean"]) > summary["ci95"] + base["ci95"]
                summary["overlaps_dr"] = not apart
    return out


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="racing")
    parser.add_argument("--algo", default=None, help="default: the paper preset's")
    parser.add_argument("--option", action="append", default=None, help="env option NAME=VALUE (default: the paper preset's)")
    parser.add_argument("--episodes", type=int, default=None, help="training episodes per run (default: the paper preset's)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument(
        "--arms", nargs="+", default=["dr", "plr", "accel", "target"], help="curricula, and 'offline' (the paper's influence; needs dr)"
    )
    parser.add_argument("--offline-search", type=int, nargs=2, default=(1000, 525), metavar=("CANDIDATES", "SEARCH"), help="the offline arm's worlds")
    parser.add_argument("--target", default=None, help="the target arm's target (default: the env's failure event)")
    parser.add_argument("--maximize", dest="maximize", action="store_true", default=None)
    parser.add_argument("--minimize", dest="maximize", action="store_false")
    parser.add_argument("--curriculum-set", action="append", default=[], help="NAME=VALUE for every curriculum arm (docs/curriculum.md)")
    parser.add_argument("--generator", type=Path, default=None, help="default: runs/quick/ENV/generator")
    parser.add_argument("--eval-worlds", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=8)
    parser.add_argument("--work", type=Path, default=None)
    parser.add_argument("--note", action="append", default=[], help="a sentence the JSON keeps (e.g. what else ran on the machine)")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)

    spec = registry.get(args.env)
    defaults = paper_defaults(spec)
    algo = args.algo or defaults["algo"]
    options = spec.parse_options(args.option) if args.option else spec.check_options(defaults["options"])
    episodes = args.episodes or defaults["episodes"]
    generator_dir = args.generator or Path("runs/quick") / spec.name / "generator"
    work = args.work or Path("runs") / f"curriculum-{spec.name}"
    target_text = args.target or spec.failure
    config = training_config(spec, algo, episodes=episodes, options=options)
    latents = world_distribution(spec, "vae", generator_dir=generator_dir)
    generator = latents.generator
    _, params = spec.make_env(options)
    z, worlds = evaluation_worlds(generator, args.eval_worlds)
    settings = parse_curriculum_settings(args.curriculum_set)

    arms, per_seed = {}, {}
    if "offline" in args.arms and ("dr" not in args.arms or args.arms.index("offline") < args.arms.index("dr")):
        raise SystemExit("--arms: the offline arm selects its worlds with dr's first agent; list dr before offline.")
    suffix = "" if episodes == defaults["episodes"] else f"-{episodes}"
    out = RESULTS / f"curriculum-{spec.name}{suffix}.json"
    for done, arm in enumerate(args.arms, start=1):
        if arm == "offline":
            counts = {"candidates": args.offline_search[0], "search_budget": args.offline_search[1], "repeats": args.repeats, "seed": 0}
            arms[arm] = offline_arm(
                spec, algo, config, options, generator, generator_dir, arms["dr"]["dirs"][0], args.seeds, work / arm, counts, not args.quiet
            )
        else:
            target = target_score(spec, target_text, args.maximize) if arm == "target" else None
            curriculum = make_curriculum(arm, latents, settings if arm != "dr" else {}, target)
            trained = train_arm(spec, algo, config, options, curriculum, args.seeds, work / arm, not args.quiet)
            arms[arm] = {"curriculum": label(curriculum), **trained}
        if "dirs" in arms[arm]:
            per_seed[arm], seconds = {}, []
            for seed, agent_dir in zip(args.seeds, arms[arm]["dirs"]):
                cache = work / "eval" / f"{arm}-s{seed}-w{args.eval_worlds}.npz"
                metrics, took = evaluate_agent(spec, agent_dir, generator_dir, worlds, args.repeats, cache)
                per_seed[arm][seed] = agent_statistics(spec, metrics, params)
                seconds.append(took)
                print(arm, seed, {k: round(v, 4) if isinstance(v, float) else v for k, v in per_seed[arm][seed].items()}, flush=True)
            arms[arm]["evaluation_wall_seconds"] = None if None in seconds else round(sum(seconds), 1)  # None: cached before kept
        result = {
            "env": spec.name,
            "algorithm": algo,
            "options": options,
            "config": config.to_dict(),
            "episodes": episodes,
            "seeds": args.seeds,
            "generator": str(generator_dir),
            "evaluation": {"worlds": args.eval_worlds, "repeats": args.repeats, "seed": EVAL_SEED, "alpha": ALPHA, "failure": spec.failure},
            "target": {"text": target_text, "maximize": args.maximize},
            "curriculum_settings": settings,
            "arms": arms,
            "arms_pending": args.arms[done:],  # written after every arm: a partial file says what is still to come
            "per_seed": per_seed,
            "summary": compare(per_seed),
            "not_run": NOT_RUN,
            "notes": args.note,
            "machine": describe_machine(),
            "command": "python benchmarks/curriculum.py " + " ".join(sys.argv[1:] if argv is None else argv),
        }
        write_text(out, json.dumps(result, indent=1, default=float))
        print(f"wrote {out} ({arm} done)", flush=True)
    return result


if __name__ == "__main__":
    main()
