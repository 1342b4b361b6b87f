"""The paper's harvest influencing experiment (§6.2.2, Figure 8b) at its budget, with the evidence kept.

    python benchmarks/influence_harvest.py                  # 5 seeds x 5,000 episodes, 500 evaluation worlds x 8
    python benchmarks/influence_harvest.py --seeds 0 1 --episodes 1000 --eval-worlds 100 --work runs/influence-small
    # issue 50 item 6 at the quick preset's scale: its G(z) and given agents, the selection confirmed
    python benchmarks/influence_harvest.py --generator runs/quick/harvest/generator --given-agent runs/quick/harvest/agent \
        --episodes 1000 --candidates 200 --search-budget 210 --eval-worlds 1000 --confirm 32 --work runs/influence-harvest-quick \
        --results benchmarks/results/influence-harvest-confirmed.json

Steps, each cached under ``--work`` (a killed run resumes where it stopped):

1. the paper's dataset of 10,000 procedural maps and the generator G(z) (harvest's ``paper`` preset),
   or ``--generator``'s;
2. the given agents: four DQNs, agent 0 may TAG, trained 5,000 episodes on the dataset, or ``--given-agent``;
3. ``experiments.influence``: the given agents play ``--candidates`` random G(z) worlds x 8;
   those with ``conflict == 0`` (the paper's selection) form the influenced distribution (with
   ``--confirm N``, only those that keep it on N fresh episodes each: ``influence.confirmation``); per
   seed, fresh default agents train on G(z) and influenced agents on the selected worlds; all
   play the same ``--eval-worlds`` random G(z) worlds x 8;
4. who collects what: every trained agent's per-agent returns on ``--diagnostic-worlds`` random
   G(z) worlds, split by whether walls cut the tagger (agent 0) off from another agent (0: skipped);
5. the selected worlds replayed: every trained agent on each influenced training world,
   ``--replay-repeats`` fresh episodes (the same keys for all, not those that confirmed the worlds):
   the failure event's and the selection's per-episode rates, influenced against default, pooled
   over seeds and paired by world (``analysis.diff.pooled_difference``).

Writes ``benchmarks/results/influence-harvest.json`` (``--results``): per-seed values, means with 95% intervals
(Student t over seeds), whether the intervals overlap, the selection, the budgets, the machine
and the paper's numbers.
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
from influence_pooled import pooled_influenced_vs_default  # noqa: E402
from machine import RESULTS, describe_machine  # noqa: E402
from train_harvest import evaluate  # noqa: E402
from worldagent import experiments  # noqa: E402
from worldagent.agents.algorithms import training_config  # noqa: E402
from worldagent.agents.distributions import world_distribution  # noqa: E402
from worldagent.agents.training import train  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.events import parse_selection  # noqa: E402
from worldagent.files import write_text  # noqa: E402
from worldagent.influence.cache import load_influenced_worlds  # noqa: E402
from worldagent.influence.confirmation import DEFAULT_REPEATS, confirmation_line, trained_on_selected  # noqa: E402
from worldagent.influence.experiment import trained_policies  # noqa: E402
from worldagent.influence.statistics import json_safe  # noqa: E402
from worldagent.worlds.dataset import WorldDataset, make_dataset  # noqa: E402
from worldagent.worlds.generator import build_generator, save_generator  # noqa: E402
from worldagent.worlds.quality import figures  # noqa: E402
from worldagent.worlds.vae import VAEConfig, train_vae  # noqa: E402

SPEC = registry.get("harvest")
PAPER = SPEC.presets["paper"]
DIAGNOSTIC_REPEATS = 2


def dataset_and_generator(work: Path, progress: bool, given: Path | None = None) -> Path:
    """``given`` if it holds a generator, else the paper preset's dataset and G(z) under ``work`` (made once);
    returns the generator directory."""
    if given is not None and (given / "generator.json").is_file():
        return given
    data_path, gen_dir = work / "dataset.npz", work / "generator"
    if not data_path.exists():
        make_dataset(SPEC, PAPER["worlds"], 0, progress=progress).save(data_path)
    if not (gen_dir / "generator.json").exists():
        data = WorldDataset.load(data_path, env=SPEC.name)
        vae = train_vae(data, VAEConfig(epochs=PAPER["vae_epochs"]), progress=progress, checkpoint_dir=gen_dir)
        generator = build_generator(vae, data)
        quality = figures(generator, data, 2000, jax.random.key(0))
        write_text(gen_dir / "quality.json", json.dumps({"structure": quality["structure"], "validity": quality["validity_after_repair"]}, indent=1))
        save_generator(gen_dir, vae, data_path, generator)
    return gen_dir


def given_agents(work: Path, options: dict, episodes: int, progress: bool) -> Path:
    """The agents whose conflict selects the worlds, trained on the dataset (resumed if killed)."""
    out = work / "agent"
    if not (out / "policy").exists():
        config = training_config(SPEC, SPEC.default_algorithm, episodes)
        distribution = world_distribution(SPEC, str(work / "dataset.npz"))
        train(SPEC, SPEC.default_algorithm, config, distribution, out, seed=0, options=options, progress=progress, resume=True)
    return out


def interval(stats: dict) -> list[float] | None:
    """[low, high] of a mean's 95% interval; None without one (a single seed)."""
    half = stats.get("ci95")
    if half is None or not np.isfinite(half):
        return None
    return [stats["mean"] - half, stats["mean"] + half]


def comparison(summary: dict) -> dict:
    """Per metric: both intervals and whether they overlap (None with a single seed)."""
    out = {}
    for metric, by_label in summary.items():
        low, high = interval(by_label["default"]), interval(by_label["influenced"])
        overlap = None if low is None or high is None else bool(low[0] <= high[1] and high[0] <= low[1])
        out[metric] = {"default": low, "influenced": high, "overlap": overlap}
    return out


def who_collects_what(influence_dir: Path, setup, count: int) -> dict:
    """Mean per-agent returns and conflict of every trained agent on ``count`` random G(z) worlds,
    split by whether walls cut the tagger off from at least one other agent."""
    z = jax.random.normal(jax.random.key(12345), (count, setup.generator.latent_dim))
    worlds = jax.tree_util.tree_map(np.asarray, setup.generator(z))
    describe = SPEC.metrics.descriptors["tagger_separated"]
    separated = np.array([describe(jax.tree_util.tree_map(lambda leaf, i=i: leaf[i], worlds)) for i in range(count)]) > 0.5
    dirs = {p.name: p / "policy" for p in sorted((influence_dir / "agents").iterdir()) if (p / "policy").exists()}
    policies = trained_policies(dirs, SPEC, greedy=False)
    rows = {}
    for name, policy in policies.items():
        metrics = evaluate(jax.random.key(7), policy, worlds, setup.env, setup.params, DIAGNOSTIC_REPEATS)
        returns = np.asarray(metrics["returns"]).mean(axis=1)  # [worlds, 4]
        conflict, equality = np.asarray(metrics["conflict"]).mean(axis=1), np.asarray(metrics["equality"]).mean(axis=1)
        rows[name] = {
            part: {
                "worlds": int(mask.sum()),
                "returns": returns[mask].mean(axis=0).round(2).tolist(),
                "tagger_share": round(float(returns[mask, 0].sum() / max(returns[mask].sum(), 1e-9)), 4),
                "conflict": round(float(conflict[mask].mean()), 4),
                "equality": round(float(equality[mask].mean()), 4),
            }
            for part, mask in (("all", np.ones(count, bool)), ("tagger_separated", separated), ("tagger_connected", ~separated))
            if mask.any()
        }
    return {"worlds": count, "repeats": DIAGNOSTIC_REPEATS, "separated_share": round(float(separated.mean()), 4), "agents": rows}


def selected_structure(influence_dir: Path) -> dict:
    """Each descriptor's mean over the selected (influenced) worlds, e.g. how often walls isolate the tagger."""
    worlds, _, _ = load_influenced_worlds(influence_dir, SPEC)
    count = len(jax.tree_util.tree_leaves(worlds)[0])
    each = [jax.tree_util.tree_map(lambda leaf, i=i: leaf[i], worlds) for i in range(count)]
    return {name: round(float(np.mean([describe(w) for w in each])), 4) for name, describe in SPEC.metrics.descriptors.items()}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--episodes", type=int, default=PAPER["episodes"], help="training episodes of every agent (paper: 5,000)")
    parser.add_argument("--candidates", type=int, default=PAPER["influence_candidates"])
    parser.add_argument("--search-budget", type=int, default=PAPER["influence_search_budget"])
    parser.add_argument("--eval-worlds", type=int, default=500)
    parser.add_argument("--diagnostic-worlds", type=int, default=300)
    parser.add_argument("--work", type=Path, default=Path("runs/influence-harvest"))
    parser.add_argument("--runs-per-program", type=int, default=None, help="agents trained as one program at most (default: from the device)")
    parser.add_argument("--generator", type=Path, default=None, help="a generator directory to use (default: the paper preset's, made under --work)")
    parser.add_argument("--given-agent", type=Path, default=None, help="the agents whose conflict selects the worlds (default: trained under --work)")
    parser.add_argument(
        "--confirm", type=int, default=DEFAULT_REPEATS, help="fresh episodes each selected world is replayed on (0: the raw selection)"
    )
    parser.add_argument(
        "--replay-repeats", type=int, default=16, help="fresh episodes of every trained agent on each influenced world (step 5; 0: skipped)"
    )
    parser.add_argument("--results", type=Path, default=None, help="the result file (default benchmarks/results/influence-harvest.json)")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)
    progress, started = not args.quiet, time.perf_counter()
    args.work.mkdir(parents=True, exist_ok=True)
    options = SPEC.check_options(SPEC.reproduce_options)
    gen_dir = dataset_and_generator(args.work, progress, args.generator)
    if args.given_agent is not None and not (args.given_agent / "policy").is_dir():
        parser.error(f"--given-agent {args.given_agent}: not a trained agent (no policy/)")
    agent_dir = args.given_agent or given_agents(args.work, options, args.episodes, progress)
    setup = experiments.setup(SPEC, str(agent_dir), gen_dir, options=options)
    influence_dir = args.work / ("influence" if args.confirm == 0 else f"influence-confirm{args.confirm}")
    result = experiments.influence(
        influence_dir,
        setup,
        SPEC.selection,
        episodes=args.episodes,
        seeds=tuple(args.seeds),
        candidates=args.candidates,
        search_budget=args.search_budget,
        eval_worlds=args.eval_worlds,
        runs_per_program=args.runs_per_program,
        progress=progress,
        confirm=args.confirm,
    )
    quality_file = gen_dir / "quality.json"
    quality = json.loads(quality_file.read_text()) if quality_file.is_file() else None
    events = {
        "failure": parse_selection(SPEC.failure, SPEC.name).resolve(SPEC.name),
        "selection": parse_selection(SPEC.selection, SPEC.name).resolve(SPEC.name),
    }
    replayed = (
        trained_on_selected(influence_dir, setup, result, events, repeats=args.replay_repeats, progress=progress) if args.replay_repeats > 0 else None
    )
    figures = {
        "command": "python benchmarks/influence_harvest.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "options": {k: list(v) if isinstance(v, tuple) else v for k, v in options.items()},
        "budgets": {  # the paper preset's dataset and VAE, the training and evaluation
            "dataset_worlds": PAPER["worlds"],
            "vae_epochs": PAPER["vae_epochs"],
            "episodes": args.episodes,
            "seeds": args.seeds,
            "candidates": args.candidates,
            "search_budget": args.search_budget,
            "eval_worlds": args.eval_worlds,
            "repeats": setup.repeats,
            "confirm": args.confirm,
            "replay_repeats": args.replay_repeats,
        },
        "generator": str(gen_dir),
        "given_agent": str(agent_dir),
        "selection": result["selection"],
        "worlds": result["worlds"],
        "confirmation": result["worlds"].get("confirmation"),  # how many of the raw selection kept the property on fresh episodes
        "selected_worlds_fresh": replayed,  # every trained agent on the influenced worlds, fresh keys, paired and pooled
        "per_seed": result["per_seed"],
        "summary": result["summary"],
        "intervals": comparison(result["summary"]),
        "pooled_influenced_vs_default": pooled_influenced_vs_default(influence_dir),  # paired by world, pooled over seeds
        "paper": {"conflict": {"default": 0.51, "influenced": 0.05}, "equality": {"default": 0.33, "influenced": 0.78}},
        "selected_structure": selected_structure(influence_dir),  # against generator_quality's G(z) means
        "who_collects_what": who_collects_what(influence_dir, setup, args.diagnostic_worlds) if args.diagnostic_worlds > 0 else None,
        "generator_quality": quality,
        "wall_seconds": round(time.perf_counter() - started, 1),
        "influence_wall_seconds": result["wall_seconds"],
        "work": str(args.work),
    }
    machine = describe_machine()
    payload = {"benchmark": "influence-harvest", "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "machine": machine, **figures}
    path = write_text(args.results or RESULTS / "influence-harvest.json", json.dumps(json_safe(payload), indent=2) + "\n")
    lines = [f"{result['worlds']['selected']} of {result['worlds']['tried']} worlds selected ({SPEC.selection}); {machine['cores']} cores"]
    if figures["confirmation"]:
        lines.append(confirmation_line(figures["confirmation"]))
    for key, row in (replayed or {}).get("pooled", {}).items():
        lines.append(
            f"selected worlds, fresh keys, {key}: default {row['base']:.4f}, influenced {row['arm']:.4f}, {row['difference']:+.4f} [{row['low']:+.4f}, {row['high']:+.4f}]"
        )
    for key in ("p_failure", "mean_conflict"):
        row = figures["pooled_influenced_vs_default"].get(key)
        if row:
            lines.append(
                f"{args.eval_worlds} fresh worlds, {key}: default {row['base']:.4f}, influenced {row['arm']:.4f}, {row['difference']:+.4f} [{row['low']:+.4f}, {row['high']:+.4f}]"
            )
    for metric, by_label in result["summary"].items():
        d, i = by_label["default"], by_label["influenced"]
        lines.append(
            f"{metric}: {d['mean']:.3f} ± {d['ci95']:.3f} -> {i['mean']:.3f} ± {i['ci95']:.3f} (overlap: {figures['intervals'][metric]['overlap']})"
        )
    print("\n".join(lines) + f"\nrecorded in {path}")
    return figures


if __name__ == "__main__":
    main()
