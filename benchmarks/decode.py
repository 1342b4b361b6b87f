"""Time G(z), racing's decode, with the nearest-track search behind the decoder's last layer and without.

    python benchmarks/decode.py [--generator runs/quick/racing/generator] [--batches 1 16 32 256]

Racing's repair picks the dataset track whose raster the decoded logits score highest; the
generator does it behind the decoder's last layer (``NearestWorld.fold``), 1,025 numbers per track
instead of 4,096. Per batch size: the warm milliseconds of one jitted G(z) call both ways (median
of ``--calls``), and on ``--agree`` latents whether both pick the same tracks. Recorded with
``machine.record("decode", ...)``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import QUICK_RUN, record, require_input  # noqa: E402
from worldagent.worlds.generator import load_generator  # noqa: E402


def milliseconds(decode, generator, z, calls: int) -> float:
    """Median warm milliseconds of ``decode(generator, z)``."""
    jax.block_until_ready(decode(generator, z))
    times = []
    for _ in range(calls):
        start = time.perf_counter()
        jax.block_until_ready(decode(generator, z))
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--generator", type=Path, default=Path("runs/quick/racing/generator"))
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 16, 32, 256])
    parser.add_argument("--calls", type=int, default=20)
    parser.add_argument("--agree", type=int, default=20_000)
    args = parser.parse_args()
    folded = load_generator(require_input(args.generator, QUICK_RUN + " --env racing"))[0]
    if folded.folded is None:
        raise SystemExit(f"the generator in {args.generator} has no folded repair (racing's nearest-track repair has one).")
    plain = folded.replace(folded=None)
    decode = jax.jit(lambda g, z: g(z))
    timings = {}
    for batch in args.batches:
        z = jax.random.normal(jax.random.key(batch), (batch, folded.latent_dim))
        timings[str(batch)] = {"plain_ms": milliseconds(decode, plain, z, args.calls), "folded_ms": milliseconds(decode, folded, z, args.calls)}
        timings[str(batch)]["speedup"] = timings[str(batch)]["plain_ms"] / timings[str(batch)]["folded_ms"]
        print(batch, {k: round(v, 2) for k, v in timings[str(batch)].items()}, flush=True)
    z = jax.random.normal(jax.random.key(0), (args.agree, folded.latent_dim))
    same = sum(int(same_worlds(decode(plain, z[i : i + 1000]), decode(folded, z[i : i + 1000])).sum()) for i in range(0, args.agree, 1000))
    print(f"the same track for {same} of {args.agree} latents", flush=True)
    result = {"generator": str(args.generator), "calls": args.calls, "milliseconds_per_call": timings, "same_track": [same, args.agree]}
    print(f"recorded in {record('decode', result)}")


def same_worlds(a, b) -> np.ndarray:
    """bool[B]: the two batches of worlds agree row by row, in every leaf."""
    rows = [
        np.asarray(x).reshape(len(x), -1) == np.asarray(y).reshape(len(y), -1)
        for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b))
    ]
    return np.all(np.concatenate(rows, axis=1), axis=1)


if __name__ == "__main__":
    main()
