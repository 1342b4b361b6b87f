"""Time generating the paper's 10,000 Resource Harvest maps (paper §5.2.1).

    python benchmarks/map_generation.py [--num-maps 10000]

Reports the time with compilation (a first call in a fresh process) and warm (a second call
on new seeds), and records them with ``machine.record("map_generation", ...)``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import record  # noqa: E402
from worldagent.envs.harvest.maps import generate_maps, seeds_from  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-maps", type=int, default=10_000)
    args = parser.parse_args()
    start = time.perf_counter()
    generate_maps(seeds_from(0, args.num_maps))
    cold = time.perf_counter() - start
    start = time.perf_counter()
    generate_maps(seeds_from(args.num_maps, args.num_maps))
    warm = time.perf_counter() - start
    print(f"{args.num_maps} maps: {cold:.2f} s with compilation, {warm:.2f} s warm")
    print(
        f"recorded in {record('map_generation', {'num_maps': args.num_maps, 'seconds_with_compile': round(cold, 3), 'seconds_warm': round(warm, 3)})}"
    )


if __name__ == "__main__":
    main()
