"""Influenced against default agents, pooled over seeds and paired by world (issue 40).

    python benchmarks/influence_pooled.py RUN/racing/influence [--record NAME]

``worldagent influence`` (and the influence benchmarks built on it) evaluates every trained agent on
the same random worlds G(z) with the same episode keys (campaigns ``influence-eval-LABEL-sSEED-wW-rR``
of the influence directory's store). That makes a world-level comparison possible beside the
per-seed t intervals: each statistic of the influenced agents minus that of the default agents,
with a hierarchical bootstrap over seeds and shared worlds (``analysis.diff.pooled_difference``:
worlds resampled together for both arms, each arm's seeds independently). Statistics:

- ``mean_METRIC``: the mean over seeds and worlds of every scalar metric the episodes hold;
- ``cvar10``: the mean over seeds of each agent's α-CVaR (10%) of the env's main metric
  (normalised where the env has bounds), higher is better;
- ``p_failure``: the share of (seed, world) pairs where the env's failure event holds.

``influence_racing.py`` and ``influence_harvest.py`` record this as ``pooled_influenced_vs_default``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import record  # noqa: E402
from worldagent.analysis.diff import CVAR_ALPHA, cvar, pooled_difference  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.errors import WorldagentError  # noqa: E402
from worldagent.events import parse_selection  # noqa: E402
from worldagent.store import RunStore  # noqa: E402

LABELS = ("default", "influenced")


def campaign_values(store: RunStore, campaign: str, names) -> dict[str, np.ndarray]:
    """{metric: f64[W]} per-world means (episodes averaged) of a campaign's scalar metrics, in world order."""
    evaluations = sorted(store.evaluations(campaign), key=lambda e: (e.generation, e.slot))
    if not evaluations:
        raise WorldagentError(f"{store.path} holds no campaign {campaign!r}; run `worldagent influence` there first.")
    values = {}
    for name in names:
        try:
            values[name] = np.array([np.mean([float(e[name]) for e in ev.episodes]) for ev in evaluations], np.float64)
        except (KeyError, TypeError, ValueError):  # a per-agent list (harvest's per-agent rewards), or a missing one
            continue
    return values


def influence_values(influence_dir: Path, prefix: str = "", seeds=None) -> tuple[object, dict[str, list[dict[str, np.ndarray]]]]:
    """(spec, {label: [per seed {metric: f64[W]} + "score", "failing"]}) of an influence directory's evaluations
    (of ``seeds``, default all of its seeds)."""
    record = json.loads((influence_dir / "influence.json").read_text())
    spec, config = registry.get(record["env"]), record["config"]
    params = spec.make_env(config.get("options") or {})[1]
    failure = parse_selection(spec.failure, spec.name)
    found: dict[str, list[dict[str, np.ndarray]]] = {label: [] for label in LABELS}
    with RunStore(influence_dir) as store:
        for label in LABELS:
            for seed in config["seeds"] if seeds is None else seeds:
                name = f"influence-eval-{prefix}{label}-s{seed}-w{config['eval_worlds']}-r{config['repeats']}"
                values = campaign_values(store, name, spec.metrics.names)
                main = values[spec.metrics.main]
                values["score"] = np.asarray(spec.metrics.normalise(main, params) if spec.metrics.bounds is not None else main, np.float64)
                failing = np.ones(len(main), bool)
                for clause in failure.clauses:
                    failing &= clause.holds(values[clause.metric])
                values["failing"] = failing.astype(np.float64)
                found[label].append(values)
    return spec, found


def pooled_influenced_vs_default(influence_dir: str | Path, prefix: str = "", resamples: int = 2000, seeds=None) -> dict:
    """{statistic: pooled_difference of influenced − default, + "apart"} over an influence directory's seeds (or
    ``seeds``) and worlds."""
    spec, found = influence_values(Path(influence_dir), prefix, seeds)
    statistics = {f"mean_{name}": (name, lambda v: float(v.mean())) for name in found["default"][0] if name not in ("score", "failing")}
    statistics |= {"cvar10": ("score", lambda v: float(cvar(v, CVAR_ALPHA, axis=1).mean())), "p_failure": ("failing", lambda v: float(v.mean()))}
    out = {"failure": spec.failure, "score": spec.metrics.main, "seeds": len(found["default"]), "worlds": len(found["default"][0]["score"])}
    for stat, (field, statistic) in statistics.items():
        arm = np.stack([agent[field] for agent in found["influenced"]])
        base = np.stack([agent[field] for agent in found["default"]])
        row = pooled_difference(arm, base, statistic, resamples=resamples)
        out[stat] = {**row, "apart": bool(row["low"] > 0 or row["high"] < 0)}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("influence_dir", type=Path, help="an influence directory (RUN/ENV/influence, or a benchmark's --work one)")
    parser.add_argument("--record", default=None, help="also write benchmarks/results/NAME-<backend>.json (with the machine)")
    args = parser.parse_args()
    result = {"influence_dir": str(args.influence_dir), **pooled_influenced_vs_default(args.influence_dir)}
    result["command"] = "python benchmarks/influence_pooled.py " + " ".join(sys.argv[1:])
    for stat, row in result.items():
        if isinstance(row, dict):
            print(
                f"{stat:>24}: default {row['base']:.4g}, influenced {row['arm']:.4g}, difference {row['difference']:+.4g} [{row['low']:+.4g}, {row['high']:+.4g}]"
            )
    if args.record:
        print(f"-> {record(args.record, result)}")


if __name__ == "__main__":
    main()
