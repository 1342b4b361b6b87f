"""Coverage of ``worldagent diff``'s paired intervals at 95%, by simulation (issue 40).

    python benchmarks/diff_coverage.py                      # synthetic settings, then racing
    python benchmarks/diff_coverage.py --replications 2000 --racing-pool 4000

Each interval is computed ``--replications`` times on fresh samples and its coverage is the share
that holds the true value:

- **synthetic**: the t interval of the paired mean difference (skewed per-world returns shared by
  both agents, B with a 10% chance per world of a collapse), Tango's score interval of
  P_B(fail) − P_A(fail) for correlated paired failures from rare to common, and identical agents'
  failures (truth 0); the α-CVaR BCa bootstrap with fewer replications (a quarter, at least 500: each runs 1,000 resamples);
- **racing**: the scripted driver (A) against a copy blind to left corners sharper than 2.3 rad
  (B, as in tests/test_worldagent_diff.py), both played once on each of ``--racing-pool`` worlds G(z),
  z ~ N(0, I), with common random numbers (a small generator on 256 tracks). That pool is the
  population: each replication draws ``--racing-worlds`` of its worlds with replacement, so the
  truth (the pool's own difference) is exact. A crashes on ~1% of worlds: with 100 worlds the
  CVaR's tail of 10 often holds none of A's crashes, and no interval from that sample can know them.

Results: ``benchmarks/results/diff-coverage-cpu.json``; the README's "Which worlds got worse?" quotes them.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import record  # noqa: E402
from worldagent.analysis import diff  # noqa: E402

# (name, P(pass, pass), P(pass, fail), P(fail, pass), P(fail, fail)) as (A, B): correlated through the world
FAILURE_CELLS = {
    "rare (0.02 -> 0.03)": (0.965, 0.015, 0.005, 0.015),
    "moderate (0.10 -> 0.15)": (0.82, 0.08, 0.03, 0.07),
    "common (0.30 -> 0.35)": (0.60, 0.10, 0.05, 0.25),
    "identical rates (0.10 -> 0.10)": (0.86, 0.04, 0.04, 0.06),
}


def covered(intervals, truth: float) -> dict:
    """{"coverage", "replications", "mean_width"} of (low, high) pairs around ``truth``."""
    intervals = np.asarray(list(intervals), np.float64)
    hits = (intervals[:, 0] <= truth + 1e-12) & (truth - 1e-12 <= intervals[:, 1])
    return {"coverage": float(hits.mean()), "replications": len(intervals), "mean_width": float(np.mean(intervals[:, 1] - intervals[:, 0]))}


def synthetic(replications: int, seed: int) -> dict:
    """Coverage of the three intervals on synthetic paired worlds."""
    rng = np.random.default_rng(seed)
    found = {}
    for worlds in (30, 100, 400):

        def returns():
            base = rng.gamma(2.0, 10.0, worlds)
            a = base[:, None] + rng.normal(0, 5, (worlds, 4))
            b = base[:, None] + 2.0 + rng.normal(0, 5, (worlds, 4)) - 20.0 * (rng.random((worlds, 1)) < 0.1)
            row = diff.paired_difference(a, b)
            return row["low"], row["high"]

        found[f"mean difference, skewed returns, W={worlds}"] = covered((returns() for _ in range(replications)), 2.0 - 2.0)
    for name, cells in FAILURE_CELLS.items():
        truth = (cells[1] + cells[3]) - (cells[2] + cells[3])
        for worlds in (50, 200, 1000):

            def failures():
                kind = rng.choice(4, worlds, p=cells)
                row = diff.paired_failures(kind >= 2, kind % 2 == 1)["difference"]
                return row["low"], row["high"]

            found[f"P(failure) difference, {name}, W={worlds}"] = covered((failures() for _ in range(replications)), truth)
    for worlds in (100, 400):
        population_a = rng.gamma(2.0, 10.0, 200_000)
        population_b = population_a + 2.0 - 20.0 * (rng.random(200_000) < 0.1)
        truth = float(diff.cvar(population_b) - diff.cvar(population_a))

        def tail():
            picks = rng.integers(0, len(population_a), worlds)
            row = diff.paired_cvar(population_a[picks], population_b[picks], resamples=1000, seed=int(rng.integers(1 << 30)))
            return row["low"], row["high"]

        found[f"CVaR(10%) difference, W={worlds}"] = covered((tail() for _ in range(max(500, replications // 4))), truth)
    return found


def racing(pool: int, worlds: int, replications: int, seed: int) -> dict:
    """Coverage on the racing driver against its blind copy, the pool of ``pool`` worlds as the population."""
    import jax.numpy as jnp

    from worldagent import differential
    from worldagent.agents.policy import Policy
    from worldagent.analysis.paired import failure_masks
    from worldagent.envs import registry
    from worldagent.envs.racing.driver import DriverParams, driver_action
    from worldagent.envs.racing.env import ACTION_DIRECTIONS
    from worldagent.events import parse_selection
    from worldagent.store import RunStore
    from worldagent.worlds.dataset import make_dataset
    from worldagent.worlds.generator import build_generator
    from worldagent.worlds.vae import VAEConfig, train_vae

    spec = registry.get("racing")
    params = spec.make_env({})[1]

    def act(p, obs, key, state):
        centreline, n = state.world.centreline, state.world.centreline.shape[0]
        index = (state.segment + jnp.arange(9)) % n
        edges = centreline[(index + 1) % n] - centreline[index]
        heading = jnp.arctan2(edges[:, 1], edges[:, 0])
        blind = jnp.sum((jnp.diff(heading) + jnp.pi) % (2 * jnp.pi) - jnp.pi) > 2.3
        straight = jnp.argmax(jnp.asarray(ACTION_DIRECTIONS) @ state.velocity).astype(jnp.int32)
        return jnp.where(blind, straight, driver_action(state, *p))

    started = time.time()
    data = make_dataset("racing", 256, 0, progress=False)
    vae = train_vae(
        data, VAEConfig(encoder=(128, 64), decoder=(64, 128), epochs=30, batch_size=16, learning_rate=2e-3, warmup_epochs=2), progress=False
    )
    setup = differential.diff_setup("racing", "scripted/driver", Policy((params, DriverParams()), act, "blind driver", privileged=True),
                                    build_generator(vae, data), repeats=1)  # fmt: skip
    import tempfile

    with tempfile.TemporaryDirectory() as folder, RunStore(folder) as store:
        evaluations = differential.prior_set(store, setup, pool, seed=seed, progress=True)
    fail_a, fail_b, a, b = failure_masks(evaluations, spec, parse_selection(spec.failure, "racing"))
    ret_a, ret_b = a["return"][:, 0], b["return"][:, 0]
    played = time.time() - started
    truths = {
        "return": float(np.mean(ret_b - ret_a)),
        "p_failure": float(fail_b.mean() - fail_a.mean()),
        "cvar": float(diff.cvar(ret_b) - diff.cvar(ret_a)),
    }
    coverage = {}
    for count in worlds:
        rng = np.random.default_rng([seed, count])
        rows = {"return": [], "p_failure": [], "cvar": []}
        for k in range(replications):
            picks = rng.integers(0, pool, count)
            row = diff.paired_difference(ret_a[picks], ret_b[picks])
            rows["return"].append((row["low"], row["high"]))
            row = diff.paired_failures(fail_a[picks], fail_b[picks])["difference"]
            rows["p_failure"].append((row["low"], row["high"]))
            if k < max(500, replications // 4):
                row = diff.paired_cvar(ret_a[picks], ret_b[picks], resamples=1000, seed=k)
                rows["cvar"].append((row["low"], row["high"]))
        coverage[f"W={count}"] = {name: covered(intervals, truths[name]) for name, intervals in rows.items()}
    return {
        "pool": pool,
        "pool_seconds": round(played, 1),
        "truth": truths,
        "pool_rates": {"p_failure_a": float(fail_a.mean()), "p_failure_b": float(fail_b.mean()), "regressed": int(np.sum(fail_b & ~fail_a))},
        "coverage": coverage,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replications", type=int, default=2000)
    parser.add_argument("--racing-pool", type=int, default=4000, help="worlds G(z) both agents play: the population (0: skip racing)")
    parser.add_argument("--racing-worlds", type=int, nargs="+", default=[100, 400, 1000], help="worlds drawn from the pool per replication")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    started = time.time()
    result = {"confidence": 0.95, "replications": args.replications, "synthetic": synthetic(args.replications, args.seed)}
    if args.racing_pool:
        result["racing"] = racing(args.racing_pool, args.racing_worlds, args.replications, args.seed)
    result["seconds"] = round(time.time() - started, 1)
    for name, row in result["synthetic"].items():
        print(f"{row['coverage']:.3f}  {name}")
    for size, rows in result.get("racing", {}).get("coverage", {}).items():
        for name, row in rows.items():
            print(f"{row['coverage']:.3f}  racing {name} ({size})")
    print(f"-> {record('diff-coverage', result)}")


if __name__ == "__main__":
    main()
