"""Online curricula against plain random worlds, judged on the worst worlds (issue 25).

    python benchmarks/curriculum.py --env racing                       # ACKTR on rays, 5 seeds x 10,000 episodes
    python benchmarks/curriculum.py --env harvest --target conflict --minimize
    python benchmarks/curriculum.py --env racing --episodes 2000 --curriculum-set buffer_size=500 --work runs/curriculum-racing-2000

Every arm trains the same algorithm, config and episode budget on G(z) of the same generator;
only the curriculum differs (``dr``: z ~ N(0, I); ``plr``, ``accel``; ``target``: toward
``--target``, by default the env's failure event). The seeds of an arm train as one program
(``agents.many.train_many``). Two arms are the paper's influence (``experiments.influence``,
whose default agents are the ``dr`` arm's, linked rather than trained again): ``offline``, its
one retrain on the worlds where dr's first agent shows the env's selection, and ``rounds``,
the phases iterated (``--rounds``, each round's agents searching and retraining again).

Every final agent then plays the same ``--eval-worlds`` fresh worlds z ~ N(0, I) (their own
seed) ``--repeats`` times, and we report per agent:

- ``mean``: the mean over worlds of the main metric (normalised to [0, 1] where the env has bounds);
- ``cvar10``: the α-CVaR at 10%, the mean over the worst 10% of those worlds (Rutherford et al. 2024);
- ``p_failure``: the share of worlds where the env's failure event holds (world means), with its
  exact (Clopper-Pearson) interval: Monte Carlo over the evaluation worlds;
- ``worst``: the worst world's main metric among them (a random search of ``--eval-worlds``);
- ``atlas_worst``: the worst world a fixed-budget failure atlas (CMA-ME, ``--atlas-budget``
  worlds, the same seed for every agent) finds on the agent, and ``atlas_worst_confirmed``, the worst
  of its elites replayed on fresh episodes (a found score is the worst of many worlds' few episodes);
- ``training_<metric>``: the env's main and highlighted metrics over the last 20% of the agent's
  training updates (its learning curve): how often it still met failures on its arm's worlds;
- ``buffer_on_target`` (the ``target`` arm, toward an event): the share of its last buffer's worlds
  whose recent episodes meet the event, what training was replaying at the end;
- the training wall time of each arm (its seeds together, from the runs' curves: resumes add up);
- ``held_out_mean``, ``held_out_p_failure``, ``held_out_failing_worlds`` (with ``--held-out``): the
  same on a given set of worlds none of the arms trained on by construction, e.g. the failing
  worlds of ``studies/transfer_failures.py`` that most ``dr`` agents fail.

Across seeds: means with 95% Student-t intervals, and whether each arm's interval overlaps
``dr``'s. Beside them, ``pooled_vs_dr``: each arm against ``dr`` over all seeds' agents and all
evaluation worlds at once, paired by world (every agent plays the same worlds with the same
episode keys), with a hierarchical bootstrap over seeds and worlds (``analysis.diff.pooled_difference``),
and whether that interval excludes 0. Every step is cached under ``--work``: a killed run resumes. Writes
``benchmarks/results/curriculum-<env>.json`` after every arm, and beside it ``...-worlds.npz``, each agent's
per-world values. A curriculum arm already recorded there with the same setup (``setup``: config, seeds,
evaluation, and the generator's and evaluation worlds' fingerprints) is taken from there rather than trained
again, so a run longer than one machine's life goes on from its committed results (``--retrain``: train it anyway).
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
from machine import QUICK_RUN, RESULTS, describe_machine, require_input  # noqa: E402
from worldagent import experiments  # noqa: E402
from worldagent.agents.algorithms import training_config  # noqa: E402
from worldagent.agents.distributions import world_distribution  # noqa: E402
from worldagent.agents.many import ManyRun, train_many  # noqa: E402
from worldagent.agents.training import CURVE_FILE, read_curve  # noqa: E402
from worldagent.analysis.diff import cvar, pooled_difference  # noqa: E402
from worldagent.analysis.intervals import clopper_pearson  # noqa: E402
from worldagent.curricula import label, make_curriculum, parse_curriculum_settings, snapshots  # noqa: E402
from worldagent.curricula.scores import target_score  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.errors import WorldagentError  # noqa: E402
from worldagent.evaluation.local import evaluate  # noqa: E402
from worldagent.events import parse_selection  # noqa: E402
from worldagent.files import write_text  # noqa: E402
from worldagent.influence.cache import TRAINED_FILE  # noqa: E402
from worldagent.influence.experiment import compared_metrics  # noqa: E402
from worldagent.influence.statistics import mean_and_ci  # noqa: E402
from worldagent.provenance import fingerprint  # noqa: E402
from worldagent.search.given import cells_fingerprint  # noqa: E402
from worldagent.search.objectives import generate  # noqa: E402
from worldagent.store import RunStore  # noqa: E402

EVAL_SEED = 20_251_126  # the evaluation worlds' own stream, apart from every training seed
ALPHA = 0.10
STATS = ("mean", "cvar10", "p_failure", "worst", "atlas_worst", "atlas_worst_confirmed")
SECONDS_KEY = "_evaluation_seconds"  # kept in each agent's evaluation cache beside its metrics
INFLUENCE_ARMS = ("offline", "rounds")


def paper_defaults(spec) -> dict:
    """The paper preset's algorithm, options and episode budget for ``spec`` (what ``--preset paper`` trains)."""
    budgets = spec.presets.get("paper", {})
    return {
        "algo": budgets.get("algo") or spec.default_algorithm,
        "options": dict(budgets.get("options") or spec.reproduce_options or {}),
        "episodes": int(budgets.get("episodes", 1000)),
    }


def curve_rows(run_dir: Path) -> list[dict[str, float]]:
    """A training run's learning curve (``curve.csv``), a row per update."""
    return read_curve(run_dir / CURVE_FILE)


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
    last = curve_rows(out_dir)[-1]
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


def link_default_agents(run_dir: Path, dr_dirs: list[str], seeds, source: str = "the dr arm's agent") -> None:
    """Make the ``dr`` arm's agents the influence experiment's default agents: the same algorithm,
    config, G(z) and seeds, so training them again would only repeat them (``source`` says whose)."""
    unfinished = [d for d in dr_dirs if not (Path(d) / "policy").is_dir()]
    if unfinished:  # linking one would let this run train into another run's directory
        raise SystemExit(
            f"{', '.join(unfinished)}: not a trained agent (no policy/) yet; finish training it, then rerun (the steps so far are cached)."
        )
    for seed, trained in zip(seeds, dr_dirs):
        link = run_dir / "agents" / f"default-s{seed}"
        if not link.exists():
            link.parent.mkdir(parents=True, exist_ok=True)
            link.symlink_to(Path(trained).resolve(), target_is_directory=True)
        if not (link / TRAINED_FILE).is_file():
            last = curve_rows(link)[-1]
            record = {"policy": "policy", "episodes": int(float(last["episodes"])), "env_steps": int(float(last["env_steps"]))}
            record |= {"wall_seconds": float(last["wall_seconds"]), "seed": int(seed), "distribution": f"G(z), z ~ N(0, I) ({source})"}
            write_text(link / TRAINED_FILE, json.dumps(record, indent=1))


def round_seconds(work: Path, r: int, seeds) -> tuple[float, float]:
    """(search, training) seconds of influence round ``r``. Training: the slowest agent's curve clock
    (resumes add up). Search: as its ``influence.json`` first said, kept in ``search-seconds.json``,
    since a rerun reads the campaigns back and writes ~0 there."""
    here = work if r == 1 else work / f"round-{r}"
    kept_file = work / "search-seconds.json"
    kept = json.loads(kept_file.read_text()) if kept_file.is_file() else {}
    if str(r) not in kept:
        walls = json.loads((here / "influence.json").read_text())["wall_seconds"]
        kept[str(r)] = walls.get("candidates", 0.0) + walls.get("search", 0.0)
        write_text(kept_file, json.dumps(kept, indent=1))
    return kept[str(r)], max(curve_seconds(here / "agents" / f"influenced-s{seed}") for seed in seeds)


def late_training(run_dir: Path, names, share: float = 0.2) -> dict[str, float]:
    """{training_<name>: mean of the curve's per-update values over its last ``share`` of updates} for the ``names`` it has."""
    rows = curve_rows(run_dir)
    late = rows[int(len(rows) * (1 - share)) :]
    return {f"training_{name}": float(np.nanmean([float(row[name]) for row in late])) for name in names if name in rows[0]}


def buffer_on_target(run_dir: Path) -> dict[str, float]:
    """{buffer_on_target: the share of the run's last buffer snapshot whose scores are > 0}: a
    ``target`` buffer scores a world by its episodes' margin to the event, > 0 where it holds."""
    last = sorted((run_dir / snapshots.FOLDER).glob("buffer-*.npz"))[-1:]
    return {"buffer_on_target": float((np.load(last[0])["score"] > 0).mean())} if last else {}


def curve_seconds(run_dir: Path) -> float:
    """The wall clock of a run's learning curve at its last update (resumes add up)."""
    return float(curve_rows(run_dir)[-1]["wall_seconds"])


def influence_arm(spec, algo, config, generator, dr_dirs: list[str], seeds, work: Path, counts: dict, rounds: int, progress: bool) -> dict:
    """The paper's influence (§6.2) over ``rounds`` rounds: dr's first agent plays ``counts["candidates"]``
    random worlds and a CMA-ES search of ``counts["search_budget"]`` more; every seed retrains from
    scratch on the worlds with the env's selection; each later round searches with that seed's
    last agent, adds what it selects, and retrains (``influence.rounds``). Round 1 is ``offline``."""
    link_default_agents(work, dr_dirs, seeds)
    setup = experiments.setup(spec.name, dr_dirs[0], generator, repeats=counts["repeats"])
    try:
        result = experiments.influence(
            work, setup, spec.selection, algo=algo, episodes=config.episodes, seeds=seeds, candidates=counts["candidates"],
            search_budget=counts["search_budget"], eval_worlds=counts["eval_worlds"], config=config, seed=0, progress=progress,
            runs_per_program=len(seeds), rounds=rounds,
        )  # fmt: skip
    except WorldagentError as error:  # e.g. no world with the selection: said, and the other arms go on
        return {"not_run": str(error), "rounds": rounds}
    here = work if rounds == 1 else work / f"round-{rounds}"
    search, train = zip(*(round_seconds(work, r, seeds) for r in range(1, rounds + 1)))
    return {
        "curriculum": f"influence, {rounds} round(s): {result['worlds']['selected']} worlds with {result['selection']['describe']} in round 1 "
        f"(of {result['worlds']['tried']} tried by the s{seeds[0]} dr agent)",
        "dirs": [str(here / "agents" / f"influenced-s{seed}") for seed in seeds],
        "wall_seconds": round(sum(train), 1),
        "search_wall_seconds": round(sum(search), 1),
        "search_episodes_per_round": (counts["candidates"] + counts["search_budget"]) * counts["repeats"],
        "training_episodes_before": "the selecting dr agent's training (the dr arm's first seed), and each earlier round's",
        "rounds": rounds,
    }


def evaluation_worlds(generator, count: int):
    z = jax.random.normal(jax.random.key(EVAL_SEED), (count, generator.latent_dim))
    return np.asarray(z), generate(generator, z)


def evaluate_agent(spec, agent_dir: str, generator, worlds, repeats: int, cache: Path) -> tuple[dict[str, np.ndarray], float | None]:
    """({metric: f64[B, R]} of the agent on the evaluation worlds, the seconds that took), cached
    (seconds None for a cache written before they were kept)."""
    if cache.is_file():
        stored = dict(np.load(cache))
        seconds = stored.pop(SECONDS_KEY, None)
        return stored, None if seconds is None else float(seconds)
    clock = time.perf_counter()
    setup = experiments.setup(spec.name, agent_dir, generator, repeats=repeats)
    metrics = evaluate(setup.env, setup.policy, worlds, repeats, jax.random.key(EVAL_SEED + 1), setup.params)
    metrics = {name: np.asarray(value, np.float64) for name, value in spec.metrics.with_derived(metrics, setup.params).items()}
    seconds = time.perf_counter() - clock
    cache.parent.mkdir(parents=True, exist_ok=True)
    with open(cache, "wb") as handle:
        np.savez(handle, **metrics, **{SECONDS_KEY: np.float64(seconds)})
    return metrics, seconds


def atlas_worst(spec, agent_dir: str, generator, repeats: int, budget: int, store, name: str, progress: bool) -> dict[str, float]:
    """The worst world (main metric, normalised where the env has bounds) a CMA-ME atlas of ``budget``
    worlds finds on the agent: ``atlas_worst`` as found (its ``repeats`` episodes, the worst of many
    worlds: biased low by the dice) and ``atlas_worst_confirmed``, the worst of its elites replayed on
    fresh episodes (``experiments.atlas``'s confirmation); the campaign ``name`` in ``store`` resumes."""
    setup = experiments.setup(spec.name, agent_dir, generator, repeats=repeats)
    main = spec.metrics.main
    found = experiments.atlas(store, setup, main, budget=budget, seed=0, name=name, progress=progress)
    worst = {
        "atlas_worst": min(e.score for e in found["evaluations"]),
        "atlas_worst_confirmed": min(cell["confirmed"][main]["mean"] for cell in found["confirmed"]["cells"]),
    }
    if spec.metrics.bounds is None:
        return {key: float(value) for key, value in worst.items()}
    return {key: float(spec.metrics.normalise(np.float64(value), setup.params)) for key, value in worst.items()}


def world_values(spec, metrics: dict[str, np.ndarray], params) -> dict[str, np.ndarray]:
    """One agent's per-world values: ``score`` f64[W] (the main metric's world means, normalised where
    the env has bounds) and ``failing`` f64[W] (1 where the env's failure event holds)."""
    main = metrics[spec.metrics.main].mean(axis=1)
    failing = np.ones(len(main), bool)
    for clause in parse_selection(spec.failure, spec.name).clauses:
        failing &= clause.holds(metrics[clause.metric].mean(axis=1))
    score = spec.metrics.normalise(main, params) if spec.metrics.bounds is not None else main
    return {"score": np.asarray(score, np.float64), "failing": failing.astype(np.float64)}


def agent_statistics(spec, metrics: dict[str, np.ndarray], params) -> dict:
    """mean, cvar10, p_failure (+ interval), worst of one agent (see module docstring)."""
    values = world_values(spec, metrics, params)
    score, failing = values["score"], values["failing"].astype(bool)
    worst_first = np.sort(score)
    tail = max(1, int(np.ceil(ALPHA * len(score))))
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


POOLED = {  # statistic of an arm's per-world values f[S, W]: what the per-seed tables average over seeds
    "mean": ("score", lambda values: float(values.mean())),
    "cvar10": ("score", lambda values: float(cvar(values, ALPHA, axis=1).mean())),
    "p_failure": ("failing", lambda values: float(values.mean())),
}


def pooled_vs_dr(values: dict[str, list[dict[str, np.ndarray]]]) -> dict:
    """{stat: {arm: pooled_difference against dr, + "apart" (the interval excludes 0)}}: every arm
    against ``dr`` over all seeds' agents on the shared evaluation worlds (a hierarchical bootstrap
    over seeds and worlds, ``analysis.diff.pooled_difference``)."""
    if "dr" not in values:
        return {}
    out: dict = {}
    for stat, (field, statistic) in POOLED.items():
        base = np.stack([agent[field] for agent in values["dr"]])
        out[stat] = {}
        for arm, agents in values.items():
            if arm != "dr":
                found = pooled_difference(np.stack([agent[field] for agent in agents]), base, statistic)
                out[stat][arm] = {**found, "apart": bool(found["low"] > 0 or found["high"] < 0)}
    return out


def worlds_file(out: Path) -> Path:
    """Where each agent's per-world values are kept beside the results ``out``."""
    return out.with_name(f"{out.stem}-worlds.npz")


def save_world_values(out: Path, worlds_of: dict[str, list[dict[str, np.ndarray]]]) -> None:
    """{arm/field: f64[S, W]} of every evaluated arm, compressed (what ``pooled_vs_dr`` needs)."""
    arrays = {f"{arm}/{name}": np.stack([agent[name] for agent in agents]) for arm, agents in worlds_of.items() for name in agents[0]}
    with open(worlds_file(out), "wb") as handle:
        np.savez_compressed(handle, **arrays)


def recorded_arms(out: Path, setup: dict) -> dict[str, dict]:
    """{arm: {"arm", "per_seed", "worlds"}} of the curriculum arms that ``out`` recorded under the same
    ``setup``, with their per-world values; empty when the file, its values or its setup differ."""
    path = worlds_file(out)
    if not (out.is_file() and path.is_file()):
        return {}
    recorded = json.loads(out.read_text())
    if recorded.get("setup") != json.loads(json.dumps(setup, default=float)):
        return {}
    arrays = np.load(path)
    found = {}
    for arm, per_seed in recorded.get("per_seed", {}).items():
        fields = sorted(key.split("/", 1)[1] for key in arrays.files if key.startswith(f"{arm}/"))
        if arm in INFLUENCE_ARMS or not fields:
            continue
        seeds = len(per_seed)
        worlds = [{name: arrays[f"{arm}/{name}"][i] for name in fields} for i in range(seeds)]
        found[arm] = {"arm": recorded["arms"][arm], "per_seed": {int(seed): values for seed, values in per_seed.items()}, "worlds": worlds}
    return found


def compare(per_seed: dict[str, dict[int, dict]]) -> dict:
    """{stat: {arm: mean_and_ci over seeds, + overlaps_dr}}."""
    out: dict = {}
    kept = dict.fromkeys(name for seeds in per_seed.values() for values in seeds.values() for name in values)
    for stat in (*STATS, *(name for name in kept if name.startswith(("mean_", "training_", "buffer_", "held_out_")))):
        out[stat] = {
            arm: mean_and_ci([values[stat] for values in seeds.values()])
            for arm, seeds in per_seed.items()
            if all(stat in values for values in seeds.values())
        }
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
        "--arms", nargs="+", default=["dr", "plr", "accel", "target"], help="curricula, and 'offline' / 'rounds' (the paper's influence; need dr)"
    )
    parser.add_argument(
        "--offline-search", type=int, nargs=2, default=(1000, 525), metavar=("CANDIDATES", "SEARCH"), help="worlds each influence round plays"
    )
    parser.add_argument("--rounds", type=int, default=3, help="the rounds arm's rounds (influence --rounds)")
    parser.add_argument(
        "--influence-eval-worlds", type=int, default=100, help="the influence experiment's own evaluation (this one's is --eval-worlds)"
    )
    parser.add_argument("--atlas-budget", type=int, default=420, help="worlds of each agent's failure atlas (0: none)")
    parser.add_argument("--target", default=None, help="the target arm's target (default: the env's failure event)")
    parser.add_argument("--maximize", dest="maximize", action="store_true", default=None)
    parser.add_argument("--minimize", dest="maximize", action="store_false")
    parser.add_argument("--curriculum-set", action="append", default=[], help="NAME=VALUE for every curriculum arm (docs/curriculum.md)")
    parser.add_argument("--generator", type=Path, default=None, help="default: runs/quick/ENV/generator")
    parser.add_argument("--eval-worlds", type=int, default=1000)
    parser.add_argument(
        "--held-out",
        type=Path,
        default=None,
        help="an .npz of latents (studies/transfer_failures.py's transferable worlds): every agent is scored on them too",
    )
    parser.add_argument("--repeats", type=int, default=8)
    parser.add_argument("--work", type=Path, default=None)
    parser.add_argument("--note", action="append", default=[], help="a sentence the JSON keeps (e.g. what else ran on the machine)")
    parser.add_argument("--retrain", action="store_true", help="train and evaluate arms the results file already records")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)

    spec = registry.get(args.env)
    defaults = paper_defaults(spec)
    algo = args.algo or defaults["algo"]
    options = spec.parse_options(args.option) if args.option else spec.check_options(defaults["options"])
    episodes = args.episodes or defaults["episodes"]
    generator_dir = require_input(args.generator or Path("runs/quick") / spec.name / "generator", f"{QUICK_RUN} --env {spec.name}")
    work = args.work or Path("runs") / f"curriculum-{spec.name}"
    target_text = args.target or spec.failure
    config = training_config(spec, algo, episodes=episodes, options=options)
    latents = world_distribution(spec, "vae", generator_dir=generator_dir)
    generator = latents.generator
    _, params = spec.make_env(options)
    z, worlds = evaluation_worlds(generator, args.eval_worlds)
    settings = parse_curriculum_settings(args.curriculum_set)
    held_latents = np.load(args.held_out)["latents"] if args.held_out is not None else np.zeros((0, generator.latent_dim))
    held_out = generate(generator, held_latents) if len(held_latents) else None  # none transferred: nothing to score

    arms, per_seed, worlds_of = {}, {}, {}
    for arm in set(args.arms) & set(INFLUENCE_ARMS):
        if "dr" not in args.arms or args.arms.index(arm) < args.arms.index("dr"):
            raise SystemExit(f"--arms: the {arm} arm selects its worlds with dr's first agent; list dr before {arm}.")
    suffix = "" if episodes == defaults["episodes"] else f"-{episodes}"
    suffix += "" if generator.repair_name == spec.default_repair else f"-{generator.repair_name}"  # e.g. curriculum-racing-open.json
    out = RESULTS / f"curriculum-{spec.name}{suffix}.json"
    setup = {  # what an arm's recorded results depend on: the same setup reuses them (recorded_arms)
        "env": spec.name,
        "algorithm": algo,
        "options": options,
        "config": config.to_dict(),
        "seeds": args.seeds,
        "generator_fingerprint": fingerprint(generator, generator.env),
        "evaluation_worlds_fingerprint": cells_fingerprint(spec, worlds),
        "evaluation": {"worlds": args.eval_worlds, "repeats": args.repeats, "seed": EVAL_SEED},
        "atlas_budget": args.atlas_budget,
        "target": {"text": target_text, "maximize": args.maximize},
        "curriculum_settings": settings,
        "held_out": None if args.held_out is None else str(args.held_out),
    }
    recorded = {} if args.retrain else recorded_arms(out, setup)
    for done, arm in enumerate(args.arms, start=1):
        if arm in recorded:
            arms[arm], per_seed[arm], worlds_of[arm] = (recorded[arm][key] for key in ("arm", "per_seed", "worlds"))
            print(f"{arm}: recorded in {out.name} under the same setup, not trained again (--retrain to)", flush=True)
        elif arm in INFLUENCE_ARMS:
            if not all(Path(d).is_dir() for d in arms["dr"]["dirs"]):
                raise SystemExit(f"the {arm} arm needs dr's agents, which {out.name} records but --work does not hold; add --retrain.")
            counts = {"candidates": args.offline_search[0], "search_budget": args.offline_search[1], "repeats": args.repeats}
            counts["eval_worlds"] = args.influence_eval_worlds
            rounds = 1 if arm == "offline" else args.rounds
            arms[arm] = influence_arm(
                spec, algo, config, generator, arms["dr"]["dirs"], args.seeds, work / "influence", counts, rounds, not args.quiet
            )
        else:
            target = target_score(spec, target_text, args.maximize) if arm == "target" else None
            curriculum = make_curriculum(arm, latents, settings if arm != "dr" else {}, target)
            trained = train_arm(spec, algo, config, options, curriculum, args.seeds, work / arm, not args.quiet)
            arms[arm] = {"curriculum": label(curriculum), **trained}
        if "dirs" in arms[arm] and arm not in recorded:
            per_seed[arm], seconds = {}, []
            for seed, agent_dir in zip(args.seeds, arms[arm]["dirs"]):
                cache = work / "eval" / f"{arm}-s{seed}-w{args.eval_worlds}.npz"
                metrics, took = evaluate_agent(spec, agent_dir, generator, worlds, args.repeats, cache)
                per_seed[arm][seed] = agent_statistics(spec, metrics, params)
                worlds_of.setdefault(arm, []).append(world_values(spec, metrics, params))
                per_seed[arm][seed] |= late_training(Path(agent_dir), (spec.metrics.main, *spec.metrics.highlighted))
                if held_out is not None:
                    cache = work / "eval" / f"{arm}-s{seed}-held-out-{args.held_out.stem}.npz"
                    scored = agent_statistics(spec, evaluate_agent(spec, agent_dir, generator, held_out, args.repeats, cache)[0], params)
                    per_seed[arm][seed] |= {f"held_out_{name}": scored[name] for name in ("mean", "p_failure", "failing_worlds")}
                if arm == "target" and args.maximize is None:
                    per_seed[arm][seed] |= buffer_on_target(Path(agent_dir))
                if args.atlas_budget:
                    with RunStore(work / "atlas") as store:
                        per_seed[arm][seed] |= atlas_worst(
                            spec, agent_dir, generator, args.repeats, args.atlas_budget, store, f"atlas-{arm}-s{seed}", not args.quiet
                        )
                seconds.append(took)
                print(arm, seed, {k: round(v, 4) if isinstance(v, float) else v for k, v in per_seed[arm][seed].items()}, flush=True)
            arms[arm]["evaluation_wall_seconds"] = None if None in seconds else round(sum(seconds), 1)  # None: cached before kept
        result = {
            "env": spec.name,
            "setup": setup,
            "algorithm": algo,
            "options": options,
            "config": config.to_dict(),
            "episodes": episodes,
            "seeds": args.seeds,
            "generator": str(generator_dir),
            "repair": generator.repair_name,
            "evaluation": {"worlds": args.eval_worlds, "repeats": args.repeats, "seed": EVAL_SEED, "alpha": ALPHA, "failure": spec.failure},
            "held_out": None if args.held_out is None else {"file": str(args.held_out), "worlds": int(len(held_latents))},
            "atlas": {"budget": args.atlas_budget, "method": "CMA-ME over the env's default descriptors", "seed": 0},
            "influence": {"selection": spec.selection, "worlds_per_round": args.offline_search, "rounds": args.rounds},
            "target": {"text": target_text, "maximize": args.maximize},
            "curriculum_settings": settings,
            "arms": arms,
            "arms_pending": args.arms[done:],  # written after every arm: a partial file says what is still to come
            "per_seed": per_seed,
            "summary": compare(per_seed),
            "pooled_vs_dr": pooled_vs_dr(worlds_of),
            "notes": args.note,
            "machine": describe_machine(),
            "command": "python benchmarks/curriculum.py " + " ".join(sys.argv[1:] if argv is None else argv),
        }
        if worlds_of:
            save_world_values(out, worlds_of)
        write_text(out, json.dumps(result, indent=1, default=float))
        print(f"wrote {out} ({arm} done)", flush=True)
    return result


if __name__ == "__main__":
    main()
