"""How much of the env's own generator does G(z) cover? Decodes against fresh procedural worlds (issue 48).

    python benchmarks/generator_coverage.py --generator runs/quick/racing/generator [--generator ...] [--decodes 1000] [--update]

Per generator directory: ``--decodes`` draws z ~ N(0, I) (seed 0) decoded and repaired, against as many
fresh worlds of the env's generator at seeds past the dataset's largest (``worlds.coverage.coverage``):
precision and recall (Kynkäänniemi et al. 2019), density and coverage (Naeem et al. 2020), k = 5, with
the fresh-against-fresh floor at a second, disjoint seed range; each descriptor's quantiles under G(z),
fresh and dataset; where the env declares them, its generator parameters' spread. Also the wall time of
the coverage figures alone. Recorded with ``machine.record("generator-coverage", ...)``; ``--update`` keeps
the recorded generators not given (a row is replaced where its ``--generator`` path is given again) and
the recorded ``note``, ``--note TEXT`` after it.
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
from machine import QUICK_RUN, RESULTS, describe_machine, record, require_input  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.worlds.coverage import coverage  # noqa: E402
from worldagent.worlds.generator import load_generator  # noqa: E402
from worldagent.worlds.quality import BATCH, _concat, _sample  # noqa: E402


def measure(directory: Path, decodes: int) -> dict:
    """The coverage figures of the generator in ``directory`` over ``decodes`` draws."""
    generator, _, data = load_generator(directory)
    spec = registry.get(generator.env)
    z = np.asarray(jax.random.normal(jax.random.key(0), (decodes, generator.latent_dim)))
    worlds = _concat([jax.tree_util.tree_map(np.asarray, _sample(generator, z[i : i + BATCH])[0]) for i in range(0, decodes, BATCH)])
    start = time.perf_counter()
    figures = coverage(spec, worlds, decodes, data)
    return {"env": generator.env, "repair": generator.repair_name, "dataset_worlds": len(data), "seconds": time.perf_counter() - start, **figures}


def merged(rows: list[dict], decodes: int, note: str | None) -> dict:
    """The recorded rows with those of the same ``generator`` replaced by ``rows``, new ones appended, and the
    recorded note with ``note`` after it (``--update``)."""
    path = RESULTS / f"generator-coverage-{describe_machine()['backend']}.json"
    if not path.exists():
        return {"generators": rows, **({"note": note} if note else {})}
    recorded = json.loads(path.read_text())
    if recorded["decodes"] != decodes:
        raise SystemExit(f"{path} was recorded with --decodes {recorded['decodes']}; rerun with it or without --update")
    fresh = {row["generator"]: row for row in rows}
    kept = [fresh.pop(row["generator"], row) for row in recorded["generators"]]
    notes = " ".join(text for text in (recorded.get("note"), note) if text)
    return {"generators": kept + list(fresh.values()), **({"note": notes} if notes else {})}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--generator", type=Path, action="append", required=True, help="A generator directory (repeatable).")
    parser.add_argument("--decodes", type=int, default=1000)
    parser.add_argument("--update", action="store_true", help="keep the recorded generators not given here; replace those given")
    parser.add_argument("--note", help="what the rows are (appended to the recorded note with --update)")
    args = parser.parse_args()
    rows = []
    for directory in args.generator:
        row = measure(require_input(directory, QUICK_RUN), args.decodes)
        rows.append({"generator": str(directory), **row})
        floor = row["floor"]
        params = row["generator_params"]
        print(
            f"{row['env']} {row['repair']}: precision {row['precision']:.3f} recall {row['recall']:.3f} density {row['density']:.3f} "
            f"coverage {row['coverage']:.3f} (fresh vs fresh: {floor['precision']:.3f} {floor['recall']:.3f} {floor['density']:.3f} "
            f"{floor['coverage']:.3f}); {row['seconds']:.1f} s"
            + (f"; parameter std ratio min {params['min_std_ratio']:.2f} median {params['median_std_ratio']:.2f}" if params else ""),
            flush=True,
        )
    result = merged(rows, args.decodes, args.note) if args.update else {"generators": rows, **({"note": args.note} if args.note else {})}
    print(record("generator-coverage", {"decodes": args.decodes, **result}))


if __name__ == "__main__":
    main()
