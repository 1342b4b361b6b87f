"""Failure probability: Monte Carlo and importance sampling against brute force (issue 15, item 2).

    python benchmarks/failure_rate.py [--width 0.5] [--envs racing harvest] [--scale 1.0]

For each env a scripted agent plays on a small generator trained here, scored by a metric whose
tail is spread finely enough to hold events of probability 1e-2, 1e-3 and 1e-4 (``ENVS``):

- racing: ``driver``, ``steps > t`` (the slowest laps, and laps not finished in time). The
  driver and the env are deterministic given the world, so one episode per world is exact.
  ``return`` does not serve: its low tail is a handful of crash tracks each of mass ~1e-3.
- harvest: ``greedy``, ``sustainability < t`` (apples taken early: the map is stripped). Its
  ``group_reward`` takes ~20 values with a floor holding >10% of the worlds. One episode per
  world (not the paper's 8, to afford the brute force); the event is about that episode, for
  every method alike. Harvest episodes cost ~25x racing's on this CPU, so its brute force and
  Monte Carlo's cap are smaller.

1. **Brute force.** ``worlds`` worlds z ~ N(0, I). Thresholds t between two distinct values of
   the metric, with tail fractions closest to 1e-2, 1e-3 and 1e-4; the brute-force fraction, with
   its exact binomial interval, is the reference.
2. **Monte Carlo to a width.** ``analysis.failure_rate.monte_carlo`` with ``target_width``: worlds
   in batches of 1,000 until the hit that brings its exact interval within ±width·P (the 18th at
   ±50%), at most ``mc_cap`` worlds. Beside it, the worlds Monte Carlo needs in expectation at the
   brute-force P (the Clopper–Pearson width at k = nP).
3. **Importance sampling to a width.** ``importance_sampling`` likewise, the search included.
4. **Monte Carlo at importance sampling's cost**: its interval with the same episodes.

Both estimators run through one array evaluator: G(z), the jitted local evaluator with the keys
a campaign gives (``evaluation_seed``), per-world means, ``score_means``; nothing is stored (the
store's writes, not the method, would dominate the time). ``--scale`` multiplies every world
count (0.05 for a smoke run). Writes ``benchmarks/results/failure-rate.json`` with the machine.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import RESULTS, describe_machine  # noqa: E402
from worldagent import experiments  # noqa: E402
from worldagent.analysis import failure_rate as fr  # noqa: E402
from worldagent.analysis.surrogate import distinct_describer  # noqa: E402
from worldagent.evaluation.local import evaluate  # noqa: E402
from worldagent.events import parse_selection  # noqa: E402
from worldagent.files import write_text  # noqa: E402
from worldagent.worlds.dataset import make_dataset  # noqa: E402
from worldagent.worlds.generator import build_generator  # noqa: E402
from worldagent.worlds.vae import VAEConfig, train_vae  # noqa: E402

ENVS = {
    "racing": {"agent": "driver", "metric": "steps", "op": ">", "repeats": 1, "worlds": 400_000, "mc_cap": 400_000, "dataset": 2048, "epochs": 40},
    "harvest": {
        "agent": "greedy",
        "metric": "sustainability",
        "op": "<",
        "repeats": 1,
        # 100,000 held 10 hits at 1e-4, a reference of ±60%; 40,000 fresh worlds played twice held 6 and 8 (docs/failure-rate.md)
        "worlds": 300_000,
        "mc_cap": 20_000,
        "dataset": 512,
        "epochs": 30,
    },
}
PROBABILITIES = (1e-2, 1e-3, 1e-4)
# Proposals tried before the recorded run, on racing with this benchmark's generator and 400,000-world reference,
# target ±50%, batches of 250 (seeds 0-2 unless said): what each covered and its worlds ratio MC / IS (search included).
TRIED = [
    "single mean shift (the first proposal), seed 0: covered 3/3; ratio 1.4 at 1e-3, 2.6 at 1e-4",
    "mixture of <= 8 shifted priors (EM, BIC), no kernels, rounds of 250: covered 8/9; ratio 1.4-2.8 at 1e-3, "
    "2.8-3.9 at 1e-4 (two of three stopped at the 50,000-world cap short of the width)",
    "mixture components with fitted isotropic scales floored at 0.3 or 0.5, seed 0: locked onto 1-2 cells, "
    "estimates 2-20x low outside their intervals at 1e-2 and 1e-3",
    "kernels of bandwidth 0.7 around the hits after the search, no wide share: covered 7/9 (2/3 missed at 1e-4); "
    "ratio 2.9-3.8 at 1e-3, 15-23 at 1e-4",
    "kernels in the search rounds too: rounds of 500 covered 6/9, ratio 3.8-4.1 at 1e-3, 16-21 at 1e-4; "
    "rounds of 250 covered 7/9, ratio 5.4-6.5 at 1e-3, 7-32 at 1e-4",
    "shorter searches (4 rounds of 500, or 8 of 250): covered 6/9 and 5/9; ratio 2.6-7.6 at 1e-3 (7.6 in runs that missed), 5.6-42 at 1e-4",
    "kept: search 10 x 500 with shifted priors, then kernels 0.7 plus the search's mixture at share 0.3: covered 8/9 "
    "(seed 2 missed at 1e-2); ratio 3.3-3.6 at 1e-3, 6.8-14.5 at 1e-4",
    "oracle bound (no search cost): a mixture centred on the reference's cells with shares by mass reaches at 1e-3 "
    "5x (scale 1), 18x (0.8), 37x (0.7); kernels of 0.7 around 50 event worlds only ~6x",
    # issue 15 item 2, second pass: the search's worlds counted in the estimate (racing, seeds 0-2, batches of 250)
    "search worlds pooled with deterministic-mixture weights p / (average of all proposals used), kernels kept in "
    "each world's own weight: on the toy z0 > 3 estimates 0.53-0.66 P, 0/10 covered (a kernel centred on a hit "
    "spikes there and shrinks exactly the hits' weights); leaving a world's own kernel out: 10/10, mean 0.97 P",
    "search worlds pooled with each batch's own weights p/q_r (unbiased given the past): toy z0 > 3 covered 4/10 "
    "(estimates 0.75-0.86 P with tight intervals, or 1.2-1.3 P with wide ones)",
    "pooled (own kernel left out), shifted-prior search 10 x 500 as before: racing covered 6/6, ratio 3.6-4.1 at 1e-3, "
    "14.2-23.3 at 1e-4 (the search's rounds hold 0-5 hits each: its level never reaches the event)",
    "pooled, with kernels around every pooled world past the search's bar (h 0.7), search stops at 20 hits: "
    "covered 6/6, ratio 4.1-6.5 at 1e-3, 13.5-21.5 at 1e-4 (kept, then reverted: below)",
    "the same, search rounds of 250: covered 4/6, ratio 4.1-7.0 at 1e-3, 18.8-23.3 at 1e-4",
    "the same, search stops at 5 or 10 hits: covered 6/6 and 5/6, ratio 4.6-5.7 and 5.1-8.3 at 1e-3 (estimates 0.6-0.8 P)",
    "the same, bandwidth 0.5, or 0.4 with 5 hits: covered 3/6 and 2/6, estimates 0.1-0.8 P (narrow kernels: later "
    "kernels sit near the worlds they were grown from and shrink their weights), ratio 5.4-10.1 at 1e-3",
    "the same, elite fraction 0.2: covered 5/6, ratio 4.0-4.3 at 1e-3; wide share 0.1: covered 4/6, ratio 5.7-8.3",
    "the kept pooled version (search stops at 20 hits), the full benchmark, seed 0 (pooled_trial in the results): racing "
    "covered 3/3, ratio 1.4 / 5.4 / 21.5 at 1e-2 / 1e-3 / 1e-4; harvest covered 1/3 (1e-2: 0.0059 [0.0030, 0.0088] "
    "against 0.010; 1e-4: 2.27e-4 [1.17e-4, 3.37e-4] against 1.0e-4), ratio 1.4 / 3.7 / 7.8: harvest's event recurs in "
    "under half of a hit world's fresh episodes, and weights fitted on such hits after the fact bias the pooled mean; "
    "not kept (the per-batch estimator above covered harvest 3/3)",
]
# issue 15 item 2, third pass: the surrogate proposal (pool of prior worlds weighted by a model of the descriptors).
# Screens replayed the sampler on pools of known values (racing 200,000, harvest the 100,000 brute-force worlds), 8 seeds.
TRIED += [
    "surrogate, ridge on [1, z, descriptors] fitted once on a 500-world pilot: racing covered 8/8 at 1e-3 (22x), 5/8 at "
    "1e-4 (154x); harvest 7/8 (3.5x), 7/8 (7.5x)",
    "the same, refitted after each batch on the proposal's own worlds: racing covered 0/6, estimates 0.45-0.72 P; weighted "
    "p/q: 6/8 and 6/8; with prior share 0.3: 1/8",
    "features with cross terms z_i z_j: the pilot overfitted, weights' relative variance 11,733 (racing 1e-3, 0.1x); "
    "latents only, no descriptors: 631 (2.2x); harvest with boosted trees: covered 0/6, with the map's cells: 2.9x",
    "kept: ridge on [1, z, z^2, descriptors], fitted once on the pilot: racing 7/8 (22x), 7/8 (154x); harvest 8/8 (3.0x), 8/8 (7.5x)",
    # fourth pass: harvest descriptors of where the apples are (screen on the 100,000 brute-force maps with their frozen
    # episodes, 8 pilots of 500; median ratio at 1e-3 / 1e-4). Correlation with sustainability in brackets.
    "harvest, each candidate added to wall share and clustering: walk from the spawns to the nearest apple (+0.68) 9.0x / "
    "20.6x; its largest (+0.35) 5.8x / 16.9x; largest 8-connected apple patch (+0.27) 3.5x / 4.8x; apples within 5 steps "
    "of a spawn (-0.45) 3.7x / 4.2x; mean distance of the apples to the spawns (+0.45) 3.3x / 3.7x; regrowth rate of the "
    "full map (+0.04), patches (-0.07), isolated apples: 2.8-3.0x (no gain). Apple count and apples reachable per agent "
    "are constant with this generator",
    "kept: harvest's descriptors apple_distance and largest_patch join the four others: 11.0x / 26.9x (worst pilot 10.0x / "
    "21.3x); with their squares too 11.3x / 30.6x; pilot 300 12.4x / 29.4x, pilot 1,000 9.2x / 32.2x (defaults kept)",
]
CHUNK = 10_000  # worlds per evaluator call in the brute force
# Carried over from the recorded file: full runs of proposals not kept, and harvest's run against a 100,000-world reference
# (replaced by 300,000: its 10 hits at 1e-4 were too few to judge an interval by).
ARCHIVED = ("search_proposal", "pooled_trial", "harvest_reference_100k")


def small_generator(env: str, size: int, epochs: int):
    """A generator trained here in seconds (the tests' small VAE on ``size`` worlds).

    ``external_agents.small_generator``'s 5 epochs leave the posterior at the prior: G(z) is then
    nearly one world. With 512 tracks and 30 epochs racing has ~500 distinct tracks in 20,000
    draws; with 2,048 and 40, ~1,900.
    """
    data = make_dataset(env, size, 0, progress=False)
    config = VAEConfig(encoder=(128, 64), decoder=(64, 128), epochs=epochs, batch_size=32, learning_rate=2e-3, warmup_epochs=2)
    return build_generator(train_vae(data, config, progress=False), data)


def metric_means(setup, metric: str):
    """``(z f64[n, dim], seeds int[n]) -> f64[n]``: ``metric`` averaged over each world's episodes, keyed as campaigns key them."""
    generate = jax.jit(lambda generator, z: generator(z))
    world_keys = jax.jit(jax.vmap(lambda seed: jax.random.split(jax.random.key(seed), setup.repeats)))

    def means(z: np.ndarray, seeds: np.ndarray) -> np.ndarray:
        worlds = generate(setup.generator, jnp.asarray(z, jnp.float32))
        keys = world_keys(jnp.asarray(seeds, jnp.uint32))
        metrics = setup.spec.metrics.with_derived(
            evaluate(setup.env, setup.policy, worlds, setup.repeats, None, setup.params, keys=keys), setup.params
        )
        return np.asarray(metrics[metric], np.float64).mean(axis=1)

    return means


def generator_hash(generator) -> str:
    """A short hash of the generator's weights: a cached brute force is reused only for the same G."""
    import hashlib

    digest = hashlib.sha256()
    for leaf in jax.tree_util.tree_leaves(generator.params):
        digest.update(np.asarray(leaf).tobytes())
    return digest.hexdigest()[:16]


def brute_force_draws(dim: int, worlds: int, seed: int):
    """The brute force's worlds, ``CHUNK`` at a time: (z f64[n, dim], seeds int[n]) from their own stream."""
    rng = np.random.default_rng([seed, 99])
    for first in range(0, worlds, CHUNK):
        n = min(CHUNK, worlds - first)
        yield rng.standard_normal((n, dim)), rng.integers(0, 2**31, n)


def brute_force(means, dim: int, worlds: int, seed: int, cache: Path | None = None, key: str = "") -> tuple[np.ndarray, float]:
    """(f64[worlds], seconds): the metric's per-world means on ``worlds`` worlds z ~ N(0, I) (their own stream and seeds).

    With ``cache``, the values and the seconds they took are kept in ``cache/{key}-{worlds}-s{seed}.npz``
    and read back on a rerun.
    """
    path = None if cache is None else Path(cache) / f"{key}-{worlds}-s{seed}.npz"
    if path is not None and path.exists():
        kept = np.load(path, allow_pickle=False)
        return kept["values"], float(kept["seconds"])
    start = time.perf_counter()
    values = np.concatenate([means(z, seeds) for z, seeds in brute_force_draws(dim, worlds, seed)])
    seconds = time.perf_counter() - start
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, values=values, seconds=seconds)
    return values, seconds


def seconds_per_world(means, dim: int, worlds: int = 2000) -> float:
    """Seconds per world of ``means`` on this machine now: ``worlds`` worlds timed after one compiled call."""
    rng = np.random.default_rng(12345)
    means(rng.standard_normal((worlds, dim)), rng.integers(0, 2**31, worlds))
    start = time.perf_counter()
    means(rng.standard_normal((worlds, dim)), rng.integers(0, 2**31, worlds))
    return (time.perf_counter() - start) / worlds


def mc_worlds_for_width(p: float, width: float) -> int | None:
    """Worlds Monte Carlo needs, in expectation, for a Clopper–Pearson interval within ±width·p (k = round(n p))."""
    if p <= 0:
        return None
    n = 16
    while True:
        k = max(1, round(n * p))
        low, high = fr.clopper_pearson(k, n)
        if (high - low) / (2 * k / n) <= width:
            return n
        n = int(n * 1.05) + 1


def threshold_for(values: np.ndarray, p: float, op: str) -> float:
    """Halfway between two distinct ``values`` f64[n], where the fraction below (``<``) or above (``>``) is closest to p, to 9 digits."""
    distinct = np.unique(values)
    middles = (distinct[:-1] + distinct[1:]) / 2
    below = np.searchsorted(np.sort(values), middles) / len(values)
    tail = below if op == "<" else 1 - below
    return float(f"{middles[np.argmin(np.abs(np.log(tail / p)))]:.9g}")


def importance_config(args) -> fr.ImportanceConfig:
    """The importance-sampling settings the command line picks (the library's defaults otherwise)."""
    return fr.ImportanceConfig(proposal=args.proposal, pool=args.pool, pilot=args.pilot)


class Described:
    """The pool's descriptors, computed once per env: every event's estimate draws the same pool (same seed)."""

    def __init__(self, describe):
        self.describe, self.kept, self.seconds = describe, {}, 0.0

    def __call__(self, z: np.ndarray) -> np.ndarray:
        key = (z.shape, z[:2].tobytes())
        if key not in self.kept:
            start = time.perf_counter()
            self.kept[key] = self.describe(z)
            self.seconds += time.perf_counter() - start
        return self.kept[key]


def run_event(means, setup, selection, reference: dict, mc_cap: int, args, describe=None) -> dict:
    """Monte Carlo and importance sampling of the event to ``--width``, and Monte Carlo at IS's cost."""
    metric = selection.metrics[0]
    dim = setup.generator.latent_dim

    def scored(z, seeds):
        return fr.score_means(selection, {metric: means(z, seeds)}, len(z) * setup.repeats)

    row = {"event": selection.text}
    importance = partial(fr.importance_sampling, config=importance_config(args), describe=describe)
    for name, estimator in (("mc", fr.monte_carlo), ("is", importance)):
        start = time.perf_counter()
        cap = mc_cap if name == "mc" else args.is_cap
        try:
            batch = 1000 if name == "mc" else args.is_batch
            estimate = estimator(scored, dim, cap, seed=args.seed, batch=batch, target_width=args.width)
        except Exception as error:  # an IS search that found nothing is a result too
            row[name] = {"error": str(error)}
            continue
        row[name] = {
            **estimate.as_dict(),
            "seconds": round(time.perf_counter() - start, 1),
            "reached_width": estimate.relative_half_width <= args.width,
            "covers_brute_force": estimate.low <= reference["estimate"] <= estimate.high,
            "estimate_inside_brute_force_interval": reference["low"] <= estimate.estimate <= reference["high"],
        }
    if "worlds" in row["is"]:
        same = fr.monte_carlo(scored, dim, row["is"]["worlds"], seed=args.seed + 1)
        row["mc_at_is_cost"] = {**same.as_dict(), "covers_brute_force": same.low <= reference["estimate"] <= same.high}
        row["mc_expected_worlds_for_width"] = mc_worlds_for_width(reference["estimate"], args.width)
        needed = row["mc_expected_worlds_for_width"]
        row["episode_ratio_mc_over_is"] = None if needed is None else round(needed * setup.repeats / row["is"]["episodes"], 1)
    return row


def seed_screen(env: str, args) -> dict:
    """Importance sampling alone on every event, once per seed of ``--screen-seeds`` (its own pool each): how often
    its interval covers the brute force, and the episodes it spends."""
    settings = ENVS[env]
    setup = experiments.setup(env, settings["agent"], small_generator(env, settings["dataset"], settings["epochs"]), repeats=settings["repeats"])
    means, dim = metric_means(setup, settings["metric"]), setup.generator.latent_dim
    values, _ = brute_force(means, dim, int(settings["worlds"] * args.scale), 0, args.cache, f"{env}-{generator_hash(setup.generator)}")
    describe, rows = Described(distinct_describer(setup.spec, setup.generator)), []
    for p in PROBABILITIES:
        threshold = threshold_for(values, p, settings["op"])
        selection = parse_selection(f"{settings['metric']} {settings['op']} {threshold!r}", env)
        truth = float(np.mean(selection.clauses[0].holds(values)))
        needed = mc_worlds_for_width(truth, args.width) * setup.repeats

        def scored(z, seeds, selection=selection):
            return fr.score_means(selection, {settings["metric"]: means(z, seeds)}, len(z) * setup.repeats)

        for seed in args.screen_seeds:
            found = fr.importance_sampling(
                scored, dim, args.is_cap, config=importance_config(args), seed=seed, batch=args.is_batch, target_width=args.width, describe=describe
            )
            row = {"target_probability": p, "event": selection.text, "brute_force": truth, "seed": seed, **found.as_dict()}
            row |= {"covers_brute_force": found.low <= truth <= found.high, "episode_ratio_mc_over_is": round(needed / found.episodes, 1)}
            rows.append(row)
            print(f"{env} {selection.text} seed {seed}: {found.estimate:.3g} [{found.low:.3g}, {found.high:.3g}] against {truth:.3g}, "
                  f"{found.episodes} episodes ({row['episode_ratio_mc_over_is']}x)", flush=True)  # fmt: skip
    return {"importance": importance_config(args).__dict__, "rows": rows, "pool_describe_seconds": round(describe.seconds, 1)}


def run_env(env: str, args) -> dict:
    settings = ENVS[env]
    repeats, metric, mc_cap = settings["repeats"], settings["metric"], int(settings["mc_cap"] * args.scale)
    setup = experiments.setup(env, settings["agent"], small_generator(env, settings["dataset"], settings["epochs"]), repeats=repeats)
    means = metric_means(setup, metric)
    key = f"{env}-{generator_hash(setup.generator)}"
    values, seconds = brute_force(means, setup.generator.latent_dim, int(settings["worlds"] * args.scale), args.seed, args.cache, key)
    per_world = seconds_per_world(means, setup.generator.latent_dim)
    print(
        f"{env}: brute force {len(values)} worlds x {repeats} episodes in {seconds:.0f} s ({key}); {per_world * 1e3:.2f} ms a world now", flush=True
    )
    if args.brute_force_only:
        return {"brute_force_worlds": len(values), "brute_force_seconds": round(seconds, 1)}
    events, describe = [], Described(distinct_describer(setup.spec, setup.generator))
    for p in PROBABILITIES:
        threshold = threshold_for(values, p, settings["op"])
        selection = parse_selection(f"{metric} {settings['op']} {threshold!r}", env)
        hits = int(np.sum(selection.clauses[0].holds(values)))
        low, high = fr.clopper_pearson(hits, len(values))
        reference = {"estimate": hits / len(values), "low": low, "high": high, "hits": hits}
        row = {
            "target_probability": p,
            "threshold": threshold,
            "brute_force": reference,
            **run_event(means, setup, selection, reference, mc_cap, args, describe),
        }
        events.append(row)
        print(summary(env, row), flush=True)
    return {
        "agent": settings["agent"],
        "metric": metric,
        "repeats": repeats,
        "mc_cap": mc_cap,
        "brute_force_worlds": len(values),
        "brute_force_episodes": len(values) * repeats,
        "brute_force_seconds": None if np.isnan(seconds) else round(seconds, 1),  # NaN: a cache filled by a mis-timed run
        "seconds_per_world": per_world,
        "pool_describe_seconds": round(describe.seconds, 1),  # decoding and describing the surrogate's pool (no episode)
        "events": events,
    }


def summary(env: str, row: dict) -> str:
    """One line per event: the brute-force P and each method's estimate, interval and episodes."""
    parts = [f"{env} {row['event']}: brute force {row['brute_force']['estimate']:.3g}"]
    for name in ("mc", "is", "mc_at_is_cost"):
        est = row.get(name, {})
        if "estimate" in est:
            parts.append(f"{name} {est['estimate']:.3g} [{est['low']:.3g}, {est['high']:.3g}] {est['episodes']} episodes")
        elif "error" in est:
            parts.append(f"{name} failed: {est['error']}")
    return "; ".join(parts)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=1.0, help="multiplies the brute-force worlds and Monte Carlo's cap of every env")
    parser.add_argument("--width", type=float, default=0.5, help="relative half-width of the 95%% interval to reach")
    parser.add_argument("--is-cap", type=int, default=50_000, help="importance sampling's worlds at most (after the search)")
    parser.add_argument("--is-batch", type=int, default=250, help="importance sampling's worlds per batch (its proposal is refitted after each)")
    parser.add_argument("--proposal", choices=fr.PROPOSALS, default="surrogate", help="importance sampling's proposal")
    parser.add_argument("--pool", type=int, default=fr.ImportanceConfig.pool, help="the surrogate's pool of prior worlds")
    parser.add_argument("--pilot", type=int, default=fr.ImportanceConfig.pilot, help="the surrogate's pilot worlds (evaluated)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--envs", nargs="+", default=["racing", "harvest"])
    parser.add_argument("--cache", type=Path, default=None, help="keep the brute-force values here and reuse them (same G, worlds, seed)")
    parser.add_argument("--brute-force-only", action="store_true", help="only the brute force (to fill --cache); writes no result")
    parser.add_argument("--screen-seeds", type=int, nargs="+", default=None, help="only importance sampling, once per seed (failure-rate-seeds.json)")
    args = parser.parse_args()
    if args.screen_seeds:
        path = RESULTS / "failure-rate-seeds.json"
        kept = {env: entry for env, entry in (json.loads(path.read_text()) if path.exists() else {}).items() if env in ENVS}
        screened = {**kept, **{env: {"when": time.strftime("%Y-%m-%dT%H:%M:%S%z"), **seed_screen(env, args)} for env in args.envs}}
        payload = {"benchmark": "failure_rate --screen-seeds", "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "machine": describe_machine()}
        payload |= {"settings": {**vars(args), "cache": str(args.cache), "importance": importance_config(args).__dict__}, **screened}
        print("->", write_text(path, json.dumps(payload, indent=2) + "\n"), flush=True)  # an env not rerun keeps its entry
        return
    start, results = time.perf_counter(), {}
    for env in args.envs:
        began = time.perf_counter()
        results[env] = {**run_env(env, args), "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "seconds": round(time.perf_counter() - began, 1)}
        if not args.brute_force_only:  # written after each env, so a late failure keeps the finished ones
            write_results(args, results, time.perf_counter() - start)


def kept_results(settings: dict) -> dict:
    """The recorded envs this run does not redo, where they were measured with the same method settings."""
    path = RESULTS / "failure-rate.json"
    old = json.loads(path.read_text()) if path.exists() else {}
    same = all(old.get("settings", {}).get(name) == settings[name] for name in ("importance", "batch", "min_hits", "width", "is_cap", "seed"))
    return {env: {"when": old["when"], **old[env]} for env in ENVS if env in old} if same else {}


def write_results(args, results: dict, seconds: float) -> None:
    """``benchmarks/results/failure-rate.json``: the machine, the settings, the proposals tried and each env's events (an env
    not rerun keeps its recorded entry while the method's settings are unchanged)."""
    settings = {
        **{key: str(value) if isinstance(value, Path) else value for key, value in vars(args).items()},
        "envs": {env: ENVS[env] for env in args.envs},
        "importance": importance_config(args).__dict__,
        "batch": {"mc": 1000, "is": args.is_batch},
        "min_hits": fr.MIN_HITS,
    }
    kept = {env: entry for env, entry in kept_results(settings).items() if env not in results}
    old = json.loads((RESULTS / "failure-rate.json").read_text()) if (RESULTS / "failure-rate.json").exists() else {}
    archived = {name: old[name] for name in ARCHIVED if name in old}
    settings["envs"] = {env: ENVS[env] for env in (*kept, *results)}
    payload = {
        "benchmark": "failure_rate",
        "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "machine": describe_machine(),
        "settings": settings,
        "seconds": round(seconds, 1),
        "tried": TRIED,
        **archived,
        **kept,
        **results,
    }
    print("->", write_text(RESULTS / "failure-rate.json", json.dumps(payload, indent=2) + "\n"), flush=True)


if __name__ == "__main__":
    main()
