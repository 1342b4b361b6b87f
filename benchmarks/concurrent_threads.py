"""Two processes on the CPU's cores at once, as ``reproduce`` runs its env chains: XLA's default threads or one each.

    python benchmarks/concurrent_threads.py

Each workload runs in two processes at the same time, first with XLA's defaults (Eigen's thread pool
over every core in each process), then with ``reproduce.pipeline.ONE_THREAD_FLAGS``; and once alone
with each. Workloads: harvest's evaluation (64 episodes per call of a 2 x 32 MLP's four agents, a
1,000-step episode), one vector episode of harvest's DQN training (40 envs, its default config) and
a VAE-sized gradient step (128 x 4,096 inputs, 1,024 and 512 hidden). Times are wall seconds per
unit after compilation; recorded in ``results/concurrent-threads-<backend>.json``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import record  # noqa: E402

HERE = Path(__file__).resolve()
WORKLOADS = ("harvest_evaluation", "harvest_dqn_episode", "vae_step")


def harvest_evaluation() -> float:
    """Seconds per episode of harvest's agents (untrained DQN networks), 64 episodes per call."""
    import jax
    import numpy as np

    from worldagent.agents import dqn
    from worldagent.agents.policy import Policy
    from worldagent.envs import registry
    from worldagent.evaluation.local import evaluate

    spec = registry.get("harvest")
    env, params = spec.make_env({"tagger": (0,)})
    network, weights = dqn.q_network(dqn.DQNConfig(), env), dqn.init_params(jax.random.key(0), dqn.DQNConfig(), env)
    policy = Policy(weights, lambda p, obs, key, state=None: dqn.q_values(network, p, obs).argmax(-1), "mlp")
    worlds = jax.tree_util.tree_map(np.asarray, spec.generate(np.arange(8)))
    evaluate(env, policy, worlds, 8, jax.random.key(0), params)
    start = time.perf_counter()
    evaluate(env, policy, worlds, 8, jax.random.key(1), params)
    return (time.perf_counter() - start) / 64


def harvest_dqn_episode() -> float:
    """Seconds per training episode of harvest's DQN (one vector episode of its 40 envs, updating every step)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from worldagent.agents import dqn
    from worldagent.agents.distributions import WorldPool
    from worldagent.envs import registry

    spec = registry.get("harvest")
    env, params = spec.make_env({"tagger": (0,)})
    config = dqn.DQNConfig(num_episodes=1, learning_starts=4_000, epsilon_decay_episodes=1_000)
    init, update = dqn._core(config, env, int(params.max_steps), dqn._unchanged_params)
    consts = (params, WorldPool.create(jax.tree_util.tree_map(jnp.asarray, spec.generate(np.arange(200)))), jnp.float32(1_000))
    state = jax.jit(init)(jax.random.key(0), consts)
    step = jax.jit(update, donate_argnums=0)
    for _ in range(2):  # compile, then fill the buffer past learning_starts
        state, _ = step(state, consts)
    jax.block_until_ready(state)
    start = time.perf_counter()
    state, _ = step(state, consts)
    jax.block_until_ready(state)
    return (time.perf_counter() - start) / config.num_envs


def vae_step() -> float:
    """Seconds per gradient step of a VAE-sized MLP autoencoder (batch 128, 4,096 inputs, 1,024 and 512 hidden)."""
    import jax

    key = jax.random.key(0)
    x, w1, w2 = jax.random.uniform(key, (128, 4096)), jax.random.normal(key, (4096, 1024)) * 0.01, jax.random.normal(key, (1024, 512)) * 0.01

    def loss(w1, w2):
        code = jax.nn.relu(jax.nn.relu(x @ w1) @ w2)
        return (((code @ w2.T) @ w1.T - x) ** 2).mean()

    grad = jax.jit(jax.grad(loss, argnums=(0, 1)))
    jax.block_until_ready(grad(w1, w2))
    start = time.perf_counter()
    for _ in range(10):
        out = grad(w1, w2)
    jax.block_until_ready(out)
    return (time.perf_counter() - start) / 10


def timed(workload: str, copies: int, one_thread: bool) -> list[float]:
    """Seconds per unit of ``workload`` in each of ``copies`` processes started together."""
    from worldagent.reproduce.pipeline import one_thread_flags

    env = {**os.environ, "XLA_FLAGS": one_thread_flags("") if one_thread else ""}
    processes = [subprocess.Popen([sys.executable, str(HERE), "--work", workload], env=env, stdout=subprocess.PIPE, text=True) for _ in range(copies)]
    return [round(float(p.communicate()[0].split()[-1]), 5) for p in processes]


def main() -> dict:
    rows = {}
    for workload in WORKLOADS:
        rows[workload] = {
            f"{label}_{copies}": timed(workload, copies, one_thread)
            for copies in (2, 1)
            for label, one_thread in (("default", False), ("one_thread", True))
        }
        print(workload, json.dumps(rows[workload]), flush=True)
    return {"unit": "wall seconds per episode (vae_step: per step) in each process", "workloads": rows}


if __name__ == "__main__":
    if sys.argv[1:2] == ["--work"]:
        print(globals()[sys.argv[2]]())
    else:
        record("concurrent-threads", main())
