"""Bayesian optimisation's own cost: seconds per suggestion at 21, 105 and 210 observations (issue 28 item 4).

    python benchmarks/bo_suggestion.py --label after                 # suggestion timings only
    python benchmarks/bo_suggestion.py --label after --compare       # plus a small `compare` of BO on racing

Suggestion timing: a BO campaign (the settings ``compare`` uses, ``OptimiserConfig()``) minimises
an objective, asking batches of ``bo_batch`` (smaller ones where needed to land on each ``n``) and
told each batch's scores, so its observations are its own earlier suggestions as in ``compare``;
the figure is the wall time of the batch it asks when it holds exactly ``n`` observations, per
suggestion. The objective is real racing returns: the score of the nearest latent of a stored
random evaluation (``--store``, default ``runs/quick/racing``, campaign ``random-return-s0``: 1,000
latents z ~ N(0, I), each world's mean return over 8 episodes; racing's G maps latents to dataset
tracks, so its return is piecewise constant in z as this is) when that store exists, else a
synthetic bumpy function of z; the JSON says which. ``--repeats`` campaigns (seeds 0, 1, ...) are
timed; mean and max over them are recorded, and the mean CPU seconds of this process (all its
threads: on a machine shared with other work, wall time also counts the waits for a core).

``--compare``: ``experiments.compare_optimisers`` with BO only, on the racing agent and generator
of ``--run`` (default ``runs/quick/racing``), minimising the return, ``--budget`` worlds per seed
for ``--seeds`` seeds, in a fresh store; the reference distribution is that run's stored random
evaluation. Recorded: each seed's best-so-far curve, ``sample_efficiency``'s rows and the BO
campaigns' wall time. Every run lands in ``benchmarks/results/bo-suggestion.json``, keyed by ``--label``.

``--optimisers-from FILE``: use another version of ``search/optimisers.py`` (e.g. ``git show
3b7896f:src/worldagent/search/optimisers.py > /tmp/old.py``), for a baseline measured back to back
with the current code under the same load.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import QUICK_RUN, RESULTS, describe_machine, require_input  # noqa: E402
from worldagent.search.optimisers import make_optimiser  # noqa: E402

OUT = RESULTS / "bo-suggestion.json"


def objective(store: Path, campaign: str):
    """(f(z[n, 10]) -> f64[n], where it comes from): the stored random evaluation's score of the
    nearest stored latent (racing's G maps a latent to a dataset track, so its return is piecewise
    constant in z too), else a synthetic bumpy function."""
    if (store / "store.sqlite").exists():
        from worldagent.store import RunStore

        with RunStore(store, create=False) as s:
            found = s.evaluations(campaign)
        if found:
            latents, scores = np.array([e.latent for e in found]), np.array([e.score for e in found])
            nearest = lambda z: scores[np.argmin(((z[:, None, :] - latents[None]) ** 2).sum(-1), axis=1)]  # noqa: E731
            return nearest, f"{store}/{campaign} ({len(found)} worlds), nearest stored latent"
    return synthetic, "synthetic"


def synthetic(z: np.ndarray) -> np.ndarray:
    """A bumpy function of z with a plateau and rare deep failures, like a trained agent's return."""
    return 60.0 - 300.0 * (np.sin(2.0 * z[:, 0]) * np.cos(1.5 * z[:, 1]) > 0.8) + 5.0 * np.sin(z[:, 2:].sum(axis=1))


def optimisers_module(path: Path | None):
    """``worldagent.search.optimisers``, or the version of it in ``path``."""
    if path is None:
        from worldagent.search import optimisers

        return optimisers
    import importlib.util

    spec = importlib.util.spec_from_file_location("baseline_optimisers", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def time_suggestions(targets: list[int], seed: int, f, config, make=make_optimiser) -> dict[int, tuple[float, float]]:
    """(wall, CPU) seconds per suggestion of one BO campaign minimising ``f``, timed for the batch it asks when it
    holds exactly ``n`` observations, for each ``n`` in ``targets`` (the observations are its own
    earlier suggestions, as in a campaign)."""
    opt = make("bo", 10, maximize=False, seed=seed, config=config)
    told, seconds = 0, {}
    while told <= max(targets):
        upcoming = [n for n in targets if n >= told]
        n = config.bo_batch if told in targets else min(config.bo_batch, upcoming[0] - told)
        start, cpu = time.perf_counter(), time.process_time()
        z = opt.ask(n)
        if told in targets:
            seconds[told] = ((time.perf_counter() - start) / n, (time.process_time() - cpu) / n)
        opt.tell(z, f(z))
        told += n
    return seconds


def compare_run(run: Path, budget: int, seeds: int, module) -> dict:
    """BO's sample efficiency in ``compare`` on ``run``'s racing agent and generator (fresh store), with ``module``'s optimisers."""
    from worldagent import experiments
    from worldagent.reports.comparison import best_so_far, sample_efficiency
    from worldagent.search import campaign
    from worldagent.store import RunStore

    setup = experiments.setup("racing", str(run / "agent"), run / "generator", repeats=8)
    with RunStore(run, create=False) as stored:
        randoms = experiments.random_scores(stored, "return", 0)
    campaign.make_optimiser = module.make_optimiser
    with tempfile.TemporaryDirectory() as tmp, RunStore(Path(tmp)) as store:
        start = time.perf_counter()
        runs = experiments.compare_optimisers(store, setup, "return", optimisers=("bo",), budget=budget, seeds=tuple(range(seeds)), progress=False)
        wall = time.perf_counter() - start
        campaign_wall = [
            max(e.finished for e in store.evaluations(experiments.comparison_campaign_name("bo", False, "return", s)))
            - min(e.started for e in store.evaluations(experiments.comparison_campaign_name("bo", False, "return", s)))
            for s in range(seeds)
        ]
    rows = sample_efficiency(runs, randoms)
    curves = [best_so_far(scores, maximize=False) for scores in runs["bo"]]
    return {
        "run": str(run),
        "budget": budget,
        "seeds": seeds,
        "random_worlds": len(randoms),
        "wall_s": round(wall, 1),
        "campaign_wall_s": [round(w, 1) for w in campaign_wall],
        "best_so_far": [[round(float(x), 3) for x in c] for c in curves],
        "best_at": {str(k): [round(float(c[k - 1]), 3) for c in curves] for k in (21, 42, 105, 210) if k <= budget},
        "rows": [{k: v for k, v in r.items() if k != "optimiser"} for r in rows],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--label", required=True, help="key of this measurement in the JSON, e.g. before / after")
    parser.add_argument("--observations", type=int, nargs="+", default=[21, 105, 210])
    parser.add_argument("--repeats", type=int, default=2, help="BO campaigns (seeds) timed")
    parser.add_argument("--store", type=Path, default=Path("runs/quick/racing"))
    parser.add_argument("--campaign", default="random-return-s0")
    parser.add_argument("--compare", action="store_true", help="also run a small BO compare")
    parser.add_argument("--run", type=Path, default=Path("runs/quick/racing"), help="a reproduce run's racing directory (agent, generator, store)")
    parser.add_argument("--budget", type=int, default=105)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--optimisers-from", type=Path, default=None, help="another version of search/optimisers.py (a baseline)")
    args = parser.parse_args()

    module = optimisers_module(args.optimisers_from)
    config = module.OptimiserConfig()
    load_before = os.getloadavg()
    f, source = objective(require_input(args.store, QUICK_RUN + " --env racing"), args.campaign)
    per_seed = [time_suggestions(args.observations, seed, f, config, module.make_optimiser) for seed in range(args.repeats)]
    timings = {}
    for n in args.observations:
        seconds, cpu = np.array([p[n][0] for p in per_seed]), np.array([p[n][1] for p in per_seed])
        timings[str(n)] = {
            "mean_s": round(float(seconds.mean()), 4),
            "max_s": round(float(seconds.max()), 4),
            "cpu_mean_s": round(float(cpu.mean()), 4),
        }
        print(f"{n} observations: {seconds.mean():.3f} s per suggestion (max over seeds {seconds.max():.3f}; CPU {cpu.mean():.3f} s)", flush=True)
    entry = {
        "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "optimisers": str(args.optimisers_from or "src/worldagent/search/optimisers.py"),
        "config": asdict(config),
        "observations_from": source,
        "repeats": args.repeats,
        "seconds_per_suggestion": timings,
        "load_before": [round(x, 2) for x in load_before],
        "load_after": [round(x, 2) for x in os.getloadavg()],
    }
    if args.compare:
        entry["compare"] = compare_run(require_input(args.run, QUICK_RUN + " --env racing"), args.budget, args.seeds, module)
        print(json.dumps(entry["compare"]["best_at"]), f"wall {entry['compare']['wall_s']} s", flush=True)
    payload = json.loads(OUT.read_text()) if OUT.exists() else {"benchmark": "bo-suggestion"}
    payload["machine"] = describe_machine()
    payload.setdefault("measurements", {})[args.label] = entry
    from worldagent.files import write_text

    write_text(OUT, json.dumps(payload, indent=2) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
