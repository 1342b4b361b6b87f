"""External agents and the Ray backend: what they cost (issue 14, item 6).

    python benchmarks/external_agents.py [--worlds 64] [--repeats 8] [--generations 5]

1. **ONNX agent, batched against one episode at a time.** An ONNX linear controller (greedy on
   its logits; it laps, see ``route_follower_weights``) drives Particle Racing on ``--worlds``
   tracks × ``--repeats`` episodes: once through the batched host evaluator (one model call per step for all
   episodes), once one episode at a time (one call per step for one observation, as the old
   ``CallablePolicy`` loop did). Both play the same episodes; the env steps they take are counted.
2. **A campaign on Ray with 2 local workers against ``--backend local``.** The scripted racing
   driver, CMA-ES, ``--generations`` generations of 21 worlds × 8 episodes on a small generator
   trained here; the time per generation after the first (compilation) and the cluster's start.

The vector env's throughput is ``benchmarks/vector_env.py``. Writes
``benchmarks/results/external-agents-<backend>.json`` with the machine.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import record  # noqa: E402
from worldagent import experiments  # noqa: E402
from worldagent.agents.loaders import load_agent  # noqa: E402
from worldagent.envs.racing.env import ParticleRacing  # noqa: E402
from worldagent.envs.racing.tracks import generate_tracks  # noqa: E402
from worldagent.evaluation.backends import make_backend  # noqa: E402
from worldagent.evaluation.local import evaluate  # noqa: E402
from worldagent.search.campaign import CampaignSpec, run_campaign  # noqa: E402
from worldagent.search.objectives import LatentObjective, Objective  # noqa: E402
from worldagent.store import RunStore  # noqa: E402
from worldagent.worlds.dataset import make_dataset  # noqa: E402
from worldagent.worlds.generator import build_generator  # noqa: E402
from worldagent.worlds.vae import VAEConfig, train_vae  # noqa: E402


def route_follower_weights(obs_size: int) -> np.ndarray:
    """f32[obs_size, 4]: logits that push toward route point 1 and against the velocity.

    Racing's observation (no road window) is position [0:2], velocity [2:4] and route points
    [4:20]; the actions push east, west, north, south. This linear controller laps every track
    we tried (16 tracks × 2: lap rate 1.0, 271 steps per episode), so its episodes are as long
    as a trained agent's.
    """
    weights = np.zeros((obs_size, 4), np.float32)
    for axis in range(2):
        for sign, action in ((1.0, 2 * axis), (-1.0, 2 * axis + 1)):
            weights[4 + 2 + axis, action] = sign  # route point 1
            weights[2 + axis, action] = -sign  # velocity
    return weights


def linear_onnx(path: Path, weights: np.ndarray) -> Path:
    """An ONNX model ``logits = obs @ weights`` (float32)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    graph = helper.make_graph(
        [helper.make_node("MatMul", ["obs", "W"], ["logits"])],
        "route_follower",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, [None, weights.shape[0]])],
        [helper.make_tensor_value_info("logits", TensorProto.FLOAT, [None, weights.shape[1]])],
        [numpy_helper.from_array(weights, "W")],
    )
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]), str(path))
    return path


def onnx_evaluation(work: Path, worlds: int, repeats: int) -> dict:
    """Steps/s of the ONNX agent, batched and one episode at a time, on the same episodes."""
    env = ParticleRacing()
    agent = load_agent("racing", linear_onnx(work / "route_follower.onnx", route_follower_weights(env.observation_shape[0])))
    tracks = generate_tracks(np.arange(worlds))
    keys = jax.random.split(jax.random.key(0), (worlds, repeats))
    evaluate(env, agent, jax.tree_util.tree_map(lambda leaf: leaf[:1], tracks), 1, None, keys=keys[:1, :1])  # compile both shapes
    evaluate(env, agent, tracks, repeats, None, keys=keys)
    start = time.perf_counter()
    batched = evaluate(env, agent, tracks, repeats, None, keys=keys)
    batched_s = time.perf_counter() - start
    start = time.perf_counter()
    single = np.zeros((worlds, repeats), np.int64)
    for b in range(worlds):
        world = jax.tree_util.tree_map(lambda leaf, b=b: leaf[b : b + 1], tracks)
        for r in range(repeats):
            single[b, r] = evaluate(env, agent, world, 1, None, keys=keys[b : b + 1, r : r + 1])["steps"][0, 0]
    single_s = time.perf_counter() - start
    steps = int(batched["steps"].sum())
    assert np.array_equal(single, batched["steps"]), "the two ways played different episodes"
    return {
        "worlds": worlds,
        "repeats": repeats,
        "env_steps": steps,
        "mean_episode_steps": round(steps / (worlds * repeats), 1),
        "lap_rate": round(float(batched["lap_completed"].mean()), 3),
        "batched": {"seconds": round(batched_s, 3), "steps_per_s": round(steps / batched_s)},
        "one_episode_at_a_time": {"seconds": round(single_s, 3), "steps_per_s": round(steps / single_s)},
        "speedup": round(single_s / batched_s, 1),
    }


def small_generator():
    """A racing generator trained here in seconds (its worlds are enough to time a campaign)."""
    data = make_dataset("racing", 512, 0, progress=False)
    vae = train_vae(data, VAEConfig(encoder=(128, 64), decoder=(64, 128), epochs=5, batch_size=32), progress=False)
    return build_generator(vae, data)


def campaign_seconds(store_dir: Path, objective, generator, generations: int, backend) -> tuple[float, list[float]]:
    """(total wall seconds, seconds of each generation after the first) of a CMA-ES campaign of 21 worlds per generation.

    A generation's time is the gap between its last stored evaluation and the previous one's, so
    the first generation (compilation, and on Ray the workers' first compile too) is left out.
    """
    spec = CampaignSpec("timing", "racing", "return", False, "cmaes", 21 * generations, 0, generator.latent_dim)
    with RunStore(store_dir) as store:
        start = time.perf_counter()
        run_campaign(store, spec, objective, progress=False, backend=backend)
        total = time.perf_counter() - start
        ends: dict[int, float] = {}
        for e in store.evaluations("timing"):
            ends[e.generation] = max(ends.get(e.generation, 0.0), e.finished)
    last = [ends[g] for g in sorted(ends)]
    return round(total, 2), [round(b - a, 3) for a, b in zip(last, last[1:])]


def ray_overhead(work: Path, generations: int) -> dict:
    """Per-generation time of the same campaign with ``--backend local`` and on 2 local Ray workers."""
    import ray

    generator = small_generator()
    setup = experiments.setup("racing", "driver", generator, repeats=8)
    objective = LatentObjective(Objective("racing", "return", False), setup.env, setup.policy, generator, 8, setup.params)
    local_total, local = campaign_seconds(work / "local", objective, generator, generations, make_backend("local"))
    start = time.perf_counter()
    backend = make_backend("ray", workers=2)
    started = time.perf_counter() - start
    ray_total, remote = campaign_seconds(work / "ray", objective, generator, generations, backend)
    ray.shutdown()
    local_median, ray_median = float(np.median(local)), float(np.median(remote))
    return {
        "generations": generations,
        "worlds_per_generation": 21,
        "repeats": 8,
        "agent": "scripted racing driver",
        "local": {"total_s": local_total, "per_generation_s": local, "median_s": round(local_median, 3)},
        "ray_2_workers": {"cluster_start_s": round(started, 2), "total_s": ray_total, "per_generation_s": remote, "median_s": round(ray_median, 3)},
        "overhead_per_generation_s": round(ray_median - local_median, 3),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=8)
    parser.add_argument("--generations", type=int, default=6)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as work:
        result = {
            "command": "python benchmarks/external_agents.py " + " ".join(sys.argv[1:]),
            "onnx_evaluation": onnx_evaluation(Path(work), args.worlds, args.repeats),
            "ray_campaign": ray_overhead(Path(work), args.generations),
        }
    print(result)
    print("->", record("external-agents", result))


if __name__ == "__main__":
    main()
