"""Harvest influencing at the quick preset's scale: does one quick run show the paper's direction?

    worldagent reproduce --preset quick --env harvest --out runs/quick      # once: dataset, generator, given agent
    python benchmarks/studies/influence_harvest_quick.py --run runs/quick --episodes 1500 --seeds 0 1 2
    python benchmarks/studies/influence_harvest_quick.py --run runs/quick --episodes 1500 --seeds 0 1 2 --dqn epsilon_decay_episodes=1000

Re-runs only the harvest influence phase of a ``reproduce --preset quick`` run directory, with
the training episodes, evaluation worlds, seeds and DQN settings given (everything else as the
quick preset: its candidate worlds and search, copied from the run, its selection, its seed).
Each setting trains in ``RUN/harvest/influence-sweep/NAME`` (cached: a rerun only records) and
is added to ``benchmarks/results/influence-harvest-quick.json`` under its name, with per-seed
values, means, and who collects what (per-agent returns of every trained agent on
``--diagnostic-worlds`` random G(z) worlds, split by whether walls cut the tagger off).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: machine and the scripts imported
from influence_harvest import SPEC, selected_structure, who_collects_what  # noqa: E402
from machine import RESULTS, describe_machine  # noqa: E402
from worldagent import experiments  # noqa: E402
from worldagent.errors import WorldagentError  # noqa: E402
from worldagent.files import write_text  # noqa: E402
from worldagent.influence.cache import PLAN_FILE  # noqa: E402
from worldagent.influence.experiment import RESULT_FILE  # noqa: E402
from worldagent.reproduce.layout import RunLayout  # noqa: E402
from worldagent.reproduce.phases import EnvContext  # noqa: E402
from worldagent.reproduce.presets import get_preset  # noqa: E402
from worldagent.store import RunStore  # noqa: E402

RESULT = RESULTS / "influence-harvest-quick.json"


def parse_setting(text: str) -> tuple[str, object]:
    """``"epsilon_decay_episodes=1000"`` -> (name, JSON value)."""
    name, _, value = text.partition("=")
    if not name or not value:
        raise WorldagentError(f"--dqn {text!r}; write NAME=VALUE, e.g. epsilon_decay_episodes=1000.")
    return name, json.loads(value)


def setting_name(episodes: int, decay: int, eval_worlds: int, seeds: int, dqn: dict) -> str:
    """The record's key: the budgets and the exploration schedule, plus any other DQN change."""
    extra = "".join(f",{k}={v}" for k, v in sorted(dqn.items()) if k != "epsilon_decay_episodes")
    return f"episodes={episodes},epsilon_decay_episodes={decay},eval_worlds={eval_worlds},seeds={seeds}{extra}"


def start_from_the_run(run_influence: Path, out: Path, as_the_phase: bool) -> None:
    """Copy the run's scored candidate and search worlds into ``out``; with ``as_the_phase`` (the
    setting is the preset's) also its trained agents and their evaluations, so they are not redone."""
    if (out / PLAN_FILE).exists():
        return
    if not (run_influence / PLAN_FILE).is_file():
        raise WorldagentError(f"{run_influence} has no finished influence phase; run `worldagent reproduce --preset quick --env harvest` first.")
    out.mkdir(parents=True, exist_ok=True)
    shutil.copy(run_influence / "store.sqlite", out / "store.sqlite")
    plan = json.loads((run_influence / PLAN_FILE).read_text())
    if as_the_phase:
        shutil.copytree(run_influence / "agents", out / "agents")
    else:
        plan.pop("training", None)  # this setting trains with its own config
        with RunStore(out) as store:
            store.delete_campaigns([c.name for c in store.campaigns() if c.name.startswith("influence-eval-")])
    write_text(out / PLAN_FILE, json.dumps(plan, indent=1))


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=Path, required=True, help="a `reproduce --preset quick` run directory")
    parser.add_argument("--episodes", type=int, default=None, help="training episodes per agent set (default: the quick preset's)")
    parser.add_argument("--eval-worlds", type=int, default=None, help="default: the quick preset's")
    parser.add_argument("--seeds", type=int, nargs="+", default=None)
    parser.add_argument("--dqn", type=parse_setting, nargs="*", default=[], help="DQNConfig changes, NAME=VALUE")
    parser.add_argument("--diagnostic-worlds", type=int, default=100)
    args = parser.parse_args(argv)
    preset = get_preset("quick")
    budgets = preset.budgets("harvest")
    episodes = args.episodes or budgets.influence_episodes
    eval_worlds = args.eval_worlds or budgets.influence_eval_worlds
    seeds = tuple(args.seeds) if args.seeds else tuple(budgets.influence_seeds)
    dqn = dict(args.dqn)
    config = EnvContext(args.run, "harvest", preset).train_config(episodes).replace(**dqn)  # as the phase trains, then the changes
    name = setting_name(episodes, config.decay_episodes, eval_worlds, len(seeds), dqn)
    layout = RunLayout(args.run, "harvest")
    out = layout.dir / "influence-sweep" / name.replace(",", "_")
    as_the_phase = not dqn and (episodes, eval_worlds) == (budgets.influence_episodes, budgets.influence_eval_worlds)
    start_from_the_run(layout.influence_dir, out, as_the_phase)
    setup = experiments.setup(SPEC, str(layout.agent_dir), layout.generator_dir, options=SPEC.check_options(SPEC.reproduce_options))
    started, cached = time.perf_counter(), (out / RESULT_FILE).is_file()
    result = experiments.influence(
        out,
        setup,
        preset.selection("harvest"),
        episodes=episodes,
        seeds=seeds,
        candidates=budgets.influence_candidates,
        search_budget=budgets.influence_search_budget,
        eval_worlds=eval_worlds,
        config=config,
        seed=preset.seed,
        progress=False,
    )
    record = json.loads(RESULT.read_text()) if RESULT.is_file() else {"benchmark": "influence-harvest-quick", "settings": {}}
    earlier = record["settings"].get(name, {})
    record["settings"][name] = {
        "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "machine": describe_machine(),
        "command": "python benchmarks/studies/influence_harvest_quick.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "budgets": {
            "influence_episodes": episodes,
            "influence_eval_worlds": eval_worlds,
            "influence_seeds": list(seeds),
            "candidates": budgets.influence_candidates,
            "search_budget": budgets.influence_search_budget,
        },
        "dqn": {"changes": dqn, "decay_episodes": config.decay_episodes, "num_envs": config.num_envs, "learning_starts": config.learning_starts},
        "worlds": result["worlds"],
        "per_seed": result["per_seed"],
        "summary": result["summary"],
        "who_collects_what": who_collects_what(out, setup, args.diagnostic_worlds),
        "selected_structure": selected_structure(out),
        # a setting trained before keeps the timings of the run that trained it (None: not recorded)
        "train_seconds": earlier.get("train_seconds") if cached else result["wall_seconds"].get("train"),
        "wall_seconds": earlier.get("wall_seconds") if cached else round(time.perf_counter() - started, 1),
    }
    write_text(RESULT, json.dumps(record, indent=2) + "\n")
    for s in seeds:
        d, i = (result["per_seed"][label][str(s)] for label in ("default", "influenced"))
        print(f"{name} seed {s}: " + ", ".join(f"{m} {d[m]:.3f} -> {i[m]:.3f}" for m in ("conflict", "equality", "group_reward")))
    return record


if __name__ == "__main__":
    main()
