"""Steps per second of jitted, vmapped random-action rollouts of both envs, and of CarRacing.

    python benchmarks/env_throughput.py                      # racing at 1, 168, 4096 (+ CarRacing-v3),
                                                             # harvest at 1, 168, 2048
    python benchmarks/env_throughput.py --env racing --batches 4096 --steps 2000 --no-carracing

Each env in a batch plays its own world (a CarRacing track; a generated harvest map, agent 0
allowed to TAG as in §6.2.2); actions are uniform random; episodes restart through
``core.step_autoreset`` as in training. Observations and rewards are folded into a checksum that
the program returns, so XLA cannot skip computing them. Timing excludes compilation (one
warm-up call) and takes the best of ``--repeats`` runs. Harvest is counted in agent-steps (one
agent acting once; 4 per env-step). Results go to ``benchmarks/results/env_throughput-<backend>.json``
with the machine's description.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import describe_machine, record  # noqa: E402
from worldagent.envs.core import step_autoreset  # noqa: E402
from worldagent.envs.harvest.env import NUM_AGENTS, Harvest, make_params  # noqa: E402
from worldagent.envs.harvest.maps import generate_maps  # noqa: E402
from worldagent.envs.racing.env import ParticleRacing  # noqa: E402
from worldagent.envs.racing.tracks import generate_tracks  # noqa: E402

DISTINCT_WORLDS = 512  # batches larger than this cycle through these worlds
DEFAULT_BATCHES = {"racing": "1,168,4096", "harvest": "1,168,2048"}


def rollout(env, params, pool, batch: int, steps: int, action_shape: tuple = ()):
    """A jitted ``run(key) -> checksum`` of ``steps`` random-action steps in ``batch`` envs."""
    worlds = jax.tree_util.tree_map(lambda x: jnp.asarray(np.resize(x, (batch, *x.shape[1:]))), pool)
    step_all = jax.vmap(lambda k, s, a: step_autoreset(env, k, s, a, params))

    @jax.jit
    def run(key):
        key_reset, key_steps = jax.random.split(key)
        obs, state = jax.vmap(env.reset, in_axes=(0, 0, None))(jax.random.split(key_reset, batch), worlds, params)

        def one_step(carry, step_key):
            state, checksum = carry
            key_action, key_env = jax.random.split(step_key)
            actions = jax.random.randint(key_action, (batch, *action_shape), 0, env.num_actions)
            obs, state, reward, _, _, _ = step_all(jax.random.split(key_env, batch), state, actions)
            return (state, checksum + obs.sum(dtype=jnp.float32) + reward.sum()), None

        (_, checksum), _ = jax.lax.scan(one_step, (state, obs.sum(dtype=jnp.float32)), jax.random.split(key_steps, steps))
        return checksum

    return run


def racing_rollout(batch: int, steps: int):
    env = ParticleRacing()
    return rollout(env, env.default_params, generate_tracks(np.arange(min(batch, DISTINCT_WORLDS))), batch, steps)


def harvest_rollout(batch: int, steps: int):
    params = make_params(can_tag=[True, False, False, False])
    pool = generate_maps(np.arange(min(batch, DISTINCT_WORLDS)))
    return rollout(Harvest(), params, pool, batch, steps, (NUM_AGENTS,))


def time_rollout(run, batch: int, steps: int, repeats: int) -> float:
    """Best-of-``repeats`` env steps per second, compilation excluded."""
    run(jax.random.key(0)).block_until_ready()
    best = float("inf")
    for i in range(repeats):
        start = time.perf_counter()
        run(jax.random.key(i + 1)).block_until_ready()
        best = min(best, time.perf_counter() - start)
    return batch * steps / best


def time_carracing(steps: int) -> float | None:
    """Random-action steps per second of Gymnasium's CarRacing-v3, or None without Box2D."""
    try:
        import gymnasium

        env = gymnasium.make("CarRacing-v3")
    except Exception as error:  # gymnasium[box2d] missing: report, don't fail
        print(f"CarRacing-v3 unavailable ({type(error).__name__}: {error}); skipping it.")
        return None
    env.reset(seed=0)
    env.action_space.seed(0)
    start = time.perf_counter()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            env.reset()
    rate = steps / (time.perf_counter() - start)
    env.close()
    return rate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", choices=["racing", "harvest", "all"], default="all")
    parser.add_argument("--batches", default=None, help="comma-separated batch sizes (default: racing 1,168,4096; harvest 1,168,2048)")
    parser.add_argument("--steps", type=int, default=1000, help="steps per rollout (batch 1 uses 10x)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--carracing-steps", type=int, default=1000)
    parser.add_argument("--no-carracing", action="store_true", help="skip timing Gymnasium's CarRacing-v3")
    args = parser.parse_args()

    print(describe_machine())
    result = {"steps": args.steps, "repeats": args.repeats}
    envs = ["racing", "harvest"] if args.env == "all" else [args.env]
    for env in envs:
        rates = {}
        for batch in (int(b) for b in (args.batches or DEFAULT_BATCHES[env]).split(",")):
            steps = args.steps * (10 if batch == 1 else 1)
            make = racing_rollout if env == "racing" else harvest_rollout
            rate = time_rollout(make(batch, steps), batch, steps, args.repeats)
            if env == "harvest":
                rate *= NUM_AGENTS  # agent-steps
            rates[str(batch)] = round(rate)
            unit = "steps/s" if env == "racing" else "agent-steps/s"
            print(f"{env:8s} batch {batch:>5}: {rate:>14,.0f} {unit}")
        result["racing_steps_per_s" if env == "racing" else "harvest_agent_steps_per_s"] = rates
    if "racing" in envs and not args.no_carracing:
        rate = time_carracing(args.carracing_steps)
        if rate is not None:
            result["carracing_v3_steps_per_s"] = round(rate, 1)
            best = max(result["racing_steps_per_s"].values())
            print(f"CarRacing-v3    batch     1: {rate:>14,.1f} steps/s  (ParticleRacing best: {best / rate:,.0f}x)")
    print(f"recorded in {record('env_throughput', result)}")


if __name__ == "__main__":
    main()
