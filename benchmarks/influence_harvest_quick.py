"""Harvest influencing at the quick preset's scale: does one quick run show the paper's direction?

    worldagent reproduce --preset quick --env harvest --out runs/quick      # once: dataset, generator, given agent
    python benchmarks/influence_harvest_quick.py --run runs/quick --episodes 2000 --eval-worlds 200 --seeds 0 1 2

Re-runs only the harvest influence phase of a ``reproduce --preset quick`` run directory, with
the training episodes, evaluation worlds and seeds given (everything else as the quick preset),
and adds the per-seed values and means to ``benchmarks/results/influence-harvest-quick.json``
under the setting's name, with who collects what (per-agent returns of every trained agent on
300 random G(z) worlds, split by whether walls cut the tagger off). A setting already finished in
``--run`` is only recorded.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from influence_harvest import SPEC, selected_structure, who_collects_what  # noqa: E402
from machine import RESULTS, describe_machine  # noqa: E402
from worldagent import experiments  # noqa: E402
from worldagent.errors import WorldagentError  # noqa: E402
from worldagent.files import write_text  # noqa: E402
from worldagent.reproduce.layout import RunLayout  # noqa: E402
from worldagent.reproduce.manifest import Manifest, phase_key  # noqa: E402
from worldagent.reproduce.pipeline import reproduce  # noqa: E402
from worldagent.reproduce.presets import get_preset  # noqa: E402

RESULT = RESULTS / "influence-harvest-quick.json"


def influence_done(run: Path, preset) -> bool:
    """Whether ``run`` finished the harvest influence phase with ``preset``'s settings."""
    try:
        return Manifest.open(run).is_done(phase_key("harvest", "influence"), preset.phase_config("harvest", "influence"))
    except WorldagentError:  # finished with other settings
        return False


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=Path, required=True, help="a `reproduce --preset quick` run directory")
    parser.add_argument("--episodes", type=int, default=None, help="training episodes per agent set (default: the quick preset's)")
    parser.add_argument("--eval-worlds", type=int, default=None)
    parser.add_argument("--seeds", type=int, nargs="+", default=None)
    args = parser.parse_args(argv)
    quick = get_preset("quick")
    budgets = quick.budgets("harvest")
    changes = {
        "influence_episodes": args.episodes or budgets.influence_episodes,
        "influence_eval_worlds": args.eval_worlds or budgets.influence_eval_worlds,
        "influence_seeds": tuple(args.seeds) if args.seeds else tuple(budgets.influence_seeds),
    }
    preset = quick.with_budgets("harvest", **changes)
    started, already_done = time.perf_counter(), influence_done(args.run, preset)
    reproduce(preset, args.run, ["harvest"], restart=[] if already_done else ["influence"], progress=False)
    layout = RunLayout(args.run, "harvest")
    result = json.loads(layout.influence_result.read_text())
    setup = experiments.setup(SPEC, str(layout.agent_dir), layout.generator_dir, options=SPEC.check_options(SPEC.reproduce_options))
    name = f"episodes={changes['influence_episodes']},eval_worlds={changes['influence_eval_worlds']},seeds={len(changes['influence_seeds'])}"
    record = json.loads(RESULT.read_text()) if RESULT.is_file() else {"benchmark": "influence-harvest-quick", "settings": {}}
    earlier = record["settings"].get(name, {})
    record["settings"][name] = {
        "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "machine": describe_machine(),
        "command": "python benchmarks/influence_harvest_quick.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "budgets": {**{k: list(v) if isinstance(v, tuple) else v for k, v in changes.items()}, "candidates": budgets.influence_candidates},
        "worlds": result["worlds"],
        "per_seed": result["per_seed"],
        "summary": result["summary"],
        "who_collects_what": who_collects_what(layout.influence_dir, setup, 300),
        "selected_structure": selected_structure(layout.influence_dir),
        # a setting finished before keeps the wall time of the run that trained it
        "wall_seconds": earlier.get("wall_seconds") if already_done and earlier else round(time.perf_counter() - started, 1),
    }
    write_text(RESULT, json.dumps(record, indent=2) + "\n")
    for metric, by_label in result["summary"].items():
        print(f"{name} {metric}: {by_label['default']['mean']:.3f} -> {by_label['influenced']['mean']:.3f}")
    return record


if __name__ == "__main__":
    main()
