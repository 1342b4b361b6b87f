"""Time generating the paper's 10,000 CarRacing tracks (paper §5.2.1) end to end.

    python benchmarks/track_generation.py [--num-tracks 10000]

Times ``generate_tracks(seeds 0..N-1)`` (walker + cut + resample + both rasters), then the
parts on their own: the walker with its cut (``upstream_loops``), the resampling, the 64×64
footprint and the packed 128×128 road mask. Prints the numbers and records them with ``machine.record("track_generation", ...)``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from machine import record  # noqa: E402
from worldagent.envs.racing.tracks import footprint, generate_tracks, rasterize, resample_loop, upstream_loops  # noqa: E402
from worldagent.envs.racing.world import NUM_POINTS, PLAYFIELD, RASTER_SIZE, ROAD_SIZE, pack_road  # noqa: E402


def timed(fn, *args, **kwargs):
    """(result, seconds) of one call."""
    start = time.perf_counter()
    result = fn(*args, **kwargs)
    return result, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-tracks", type=int, default=10_000)
    args = parser.parse_args()
    seeds = np.arange(args.num_tracks)

    tracks, total = timed(generate_tracks, seeds)
    (loops, retries), walker = timed(upstream_loops, seeds, return_retries=True)
    centrelines, resample = timed(lambda: np.stack([resample_loop(loop[:, 2:], NUM_POINTS) for loop in loops]) / PLAYFIELD)
    centrelines = centrelines.astype(np.float32)
    raster, raster_time = timed(footprint, centrelines, RASTER_SIZE)
    road, road_time = timed(lambda: pack_road(rasterize(centrelines, ROAD_SIZE)))
    assert np.array_equal(raster, tracks.raster) and np.array_equal(road, tracks.road)

    result = {
        "num_tracks": int(args.num_tracks),
        "seconds": round(total, 3),
        "tracks_per_second": round(args.num_tracks / total, 1),
        "parts_seconds": {
            "walker_and_cut": round(walker, 3),
            "resample": round(resample, 3),
            f"footprint_{RASTER_SIZE}": round(raster_time, 3),
            f"packed_road_{ROAD_SIZE}": round(road_time, 3),
        },
        "retries": int(retries.sum()),
    }
    print(f"{args.num_tracks} tracks in {total:.2f} s ({result['tracks_per_second']} tracks/s)")
    for name, seconds in result["parts_seconds"].items():
        print(f"  {name:16s} {seconds:7.2f} s")
    print(f"  retries: {result['retries']}")
    if args.num_tracks == 10_000:
        print(f"recorded in {record('track_generation', result)}")


if __name__ == "__main__":
    main()
