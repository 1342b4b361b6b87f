"""The sections of ``device_check.py`` (issue 43), each run in a child process of its own.

    python benchmarks/device_sections.py NAME --work DIR --part FILE [--smoke] [--cap SECONDS]

``device_check.py`` runs each section here in a process of its own, killed at the section's
time cap: the parent never imports JAX (it would take the GPU's memory from its children), and a
section's results are written to ``--part`` after every measurement, so a section cut short by
its cap still reports what it measured. The sizes are ``SIZES[full|smoke]``, with the fields
that ``device_check.py --set`` changes (the environment variable ``SIZES_VARIABLE``, JSON). The
training sections (many runs, reproduce) are in ``device_runs.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import device_runs  # noqa: E402

# sizes per mode: the GPU run's, and --smoke's (tiny: the whole check in under a minute on 2 CPU cores)
SIZES = {
    "full": {
        "env_batches": (4096, 65536),
        "env_steps": 200,
        "env_repeats": 3,
        "env_max_batch": 2**24,
        "algos": ("ppo", "acktr", "dqn"),
        "seeds": (5, 1, 10),  # 5 first: the comparison; 10 last, the dearest
        "episodes": {"ppo": 3000, "acktr": 3000, "dqn": 1200},  # 10x many-runs.json's CPU budgets: at those, compilation was 95% of a GPU run
        "pool": 1000,
        "dataset": 10_000,  # the paper's: the nearest repair scores every dataset world
        "vae_hidden": (1024, 512),
        "vae_epochs": 1,
        "latents": (32, 1024, 16384),
        "decode_calls": 5,
        "eval_worlds": 1000,
        "repeats": 8,
        "timing_repeats": 2,
        "preset": "quick",
    },
    "smoke": {
        "env_batches": (8,),
        "env_steps": 20,
        "env_repeats": 1,
        "env_max_batch": 16,
        "algos": ("ppo",),  # one algorithm: each costs two compilations, and ACKTR's and DQN's take 10-20 s on 2 cores
        "seeds": (1,),  # both ways in ~20 s on 2 cores
        "episodes": {"ppo": 16, "acktr": 32, "dqn": 1},
        "pool": 32,
        "dataset": 64,
        "vae_hidden": (64, 32),
        "vae_epochs": 0,  # untrained: its compilation would take a seventh of the smoke run
        "latents": (4, 32),
        "decode_calls": 1,
        "eval_worlds": 16,
        "repeats": 2,
        "timing_repeats": 1,
        "preset": "tiny",
    },
}
SIZES_VARIABLE = "WORLDAGENT_DEVICE_SIZES"  # JSON: sizes that override SIZES' (device_check.py --set)
STEPS_PER_CALL = 2**26  # env-steps of one timed rollout at most: millions of envs take 20 steps, not 200
MEMORY_SHARE = 0.8  # the largest env batch may use this share of the device's memory (XLA's own estimate)


@dataclass
class Part:
    """One section's results, written to ``path`` after every measurement (the parent may kill us)."""

    path: Path
    work: Path
    smoke: bool
    deadline: float
    data: dict = field(default_factory=dict)

    @property
    def sizes(self) -> dict:
        return {**SIZES["smoke" if self.smoke else "full"], **json.loads(os.environ.get(SIZES_VARIABLE) or "{}")}

    def left(self) -> float:
        return self.deadline - time.time()

    def put(self, key: str, value) -> None:
        self.data[key] = value
        self.save()

    def save(self) -> None:
        tmp = self.path.with_suffix(".tmp")
        tmp.write_text(json.dumps(self.data, indent=1, default=float))
        tmp.replace(self.path)


# -- machine ---------------------------------------------------------------------------------------


def machine(part: Part) -> None:
    """JAX's view of the device: versions, backend, device kind, memory, the CUDA plugin."""
    from importlib import metadata

    import jax

    from machine import describe_machine

    info = describe_machine()
    device = jax.devices()[0]
    stats = device.memory_stats() or {}
    info["memory_limit_gib"] = round(stats["bytes_limit"] / 2**30, 1) if "bytes_limit" in stats else None
    info["jaxlib"] = metadata.version("jaxlib")
    info["platform_version"] = _platform_version()
    info["jax_plugins"] = {d.metadata["Name"]: d.version for d in metadata.distributions() if d.metadata["Name"].lower().startswith("jax-cuda")}
    info["packages"] = {name: _version(name) for name in ("flax", "optax", "numpy", "scipy", "cma", "ribs", "gymnasium", "bayesian-optimization")}
    part.put("jax", info)


def _platform_version() -> str | None:
    """The backend's own version text (on a GPU: its CUDA and cuDNN), where JAX says it."""
    try:
        import jax.extend

        return str(jax.extend.backend.get_backend().platform_version)
    except Exception:  # private-ish API: a version text is a nicety, never a failure
        return None


def _version(name: str) -> str | None:
    from importlib import metadata

    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


# -- env throughput ------------------------------------------------------------------------------


def device_rollout(env, params, batch: int, steps: int, action_shape: tuple = ()):
    """``run(key, pool) -> checksum``: ``env_throughput.rollout`` with the worlds gathered on the device
    from a small pool (at millions of envs a host-side copy per env would be gigabytes)."""
    import jax
    import jax.numpy as jnp

    from worldagent.envs.core import step_autoreset

    step_all = jax.vmap(lambda k, s, a: step_autoreset(env, k, s, a, params))

    def run(key, pool):
        size = jax.tree_util.tree_leaves(pool)[0].shape[0]
        worlds = jax.tree_util.tree_map(lambda x: x[jnp.arange(batch) % size], pool)
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


def env_setup(name: str):
    """(env, params, a pool of 512 worlds, action shape, agent-steps per env-step) of racing or harvest."""
    import numpy as np

    from env_throughput import DISTINCT_WORLDS
    from worldagent.envs.harvest.env import NUM_AGENTS, Harvest, make_params
    from worldagent.envs.harvest.maps import generate_maps
    from worldagent.envs.racing.env import ParticleRacing
    from worldagent.envs.racing.tracks import generate_tracks

    seeds = np.arange(DISTINCT_WORLDS)
    if name == "racing":
        env = ParticleRacing()
        return env, env.default_params, generate_tracks(seeds), (), 1
    return Harvest(), make_params(can_tag=[True, False, False, False]), generate_maps(seeds), (NUM_AGENTS,), NUM_AGENTS


def compiled_rollout(setup, batch: int, steps: int):
    """(the compiled program, the bytes XLA says it needs) of ``batch`` envs for ``steps`` steps."""
    import jax

    env, params, pool, action_shape, _ = setup
    compiled = jax.jit(device_rollout(env, params, batch, steps, action_shape)).lower(jax.random.key(0), pool).compile()
    memory = compiled.memory_analysis()
    needed = sum(int(getattr(memory, f"{kind}_size_in_bytes", 0) or 0) for kind in ("temp", "argument", "output")) if memory else 0
    return compiled, needed


def time_batch(setup, batch: int, sizes: dict) -> dict:
    """Steps/s (agent-steps/s for harvest) of ``batch`` envs, best of ``env_repeats``; the memory XLA planned.
    Rollouts of at most ``STEPS_PER_CALL`` env-steps (at least 20 steps): a large batch takes fewer steps."""
    from env_throughput import time_rollout

    steps = max(20, min(sizes["env_steps"], STEPS_PER_CALL // batch))
    compiled, needed = compiled_rollout(setup, batch, steps)
    rate = time_rollout(lambda key: compiled(key, setup[2]), batch, steps, sizes["env_repeats"]) * setup[4]
    return {"steps_per_s": round(rate), "steps": steps, "memory_mib": round(needed / 2**20, 1)}


def largest_batch(measured: int, needed: int, limit: int, cap: int) -> int:
    """The largest power of two of envs whose memory, scaled from ``measured`` envs needing
    ``needed`` bytes, fits ``MEMORY_SHARE`` of ``limit``; at most ``cap``."""
    batch = measured
    while batch * 2 <= cap and needed * (batch * 2) / measured <= MEMORY_SHARE * limit:
        batch *= 2
    return batch


def env_throughput(part: Part) -> None:
    """Racing steps/s and harvest agent-steps/s at the fixed batches and the largest that fits."""
    from worldagent.agents.many import device_memory

    sizes, limit = part.sizes, device_memory()
    part.put("memory_limit_gib", round(limit / 2**30, 1))
    for name in ("racing", "harvest"):
        setup, rates = env_setup(name), {}
        for batch in sizes["env_batches"]:
            rates[str(batch)] = time_batch(setup, batch, sizes)
            part.put(name, rates)
            print(f"{name} batch {batch}: {rates[str(batch)]}", flush=True)
        last = sizes["env_batches"][-1]
        rates["largest"] = largest_fitting(setup, last, int(rates[str(last)]["memory_mib"] * 2**20), limit, sizes)
        part.put(name, rates)
        print(f"{name} largest: {rates['largest']}", flush=True)


def largest_fitting(setup, last: int, needed: int, limit: int, sizes: dict) -> dict:
    """Time the largest batch predicted to fit; halve it while XLA plans too much or runs out."""
    batch = largest_batch(last, max(needed, 1), limit, sizes["env_max_batch"])
    while batch > last:
        try:
            result = time_batch(setup, batch, sizes)
        except Exception as error:  # XlaRuntimeError RESOURCE_EXHAUSTED: try half
            if "RESOURCE_EXHAUSTED" not in str(error) and "out of memory" not in str(error).lower():
                raise
            batch //= 2
            continue
        return {"batch": batch, **result}
    return {"batch": last, "note": f"no batch above {last} fits {MEMORY_SHARE:.0%} of the device's memory"}


# -- decode and search ---------------------------------------------------------------------------


def racing_generators(part: Part) -> dict:
    """Racing's G(z) with both repairs, over a dataset of ``dataset`` tracks and a VAE trained
    ``vae_epochs`` (a decode's cost depends on the shapes, not on how well the VAE learnt)."""
    from worldagent.worlds.dataset import make_dataset
    from worldagent.worlds.generator import build_generator

    sizes, start = part.sizes, time.perf_counter()
    data = make_dataset("racing", sizes["dataset"], 0, progress=False)
    part.put("dataset", {"tracks": sizes["dataset"], "seconds": round(time.perf_counter() - start, 2)})
    vae = racing_vae(part, data)
    return {name: build_generator(vae, data, repair_name=name) for name in ("nearest", "open")}


def racing_vae(part: Part, data):
    """The paper's VAE over ``data``, trained ``vae_epochs`` (0: as initialised); the training time recorded."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from worldagent.worlds.vae import TrainedVAE, VAEConfig, make_vae, train_vae

    hidden, epochs = tuple(part.sizes["vae_hidden"]), part.sizes["vae_epochs"]
    config = VAEConfig(encoder=hidden, decoder=hidden[::-1], epochs=max(1, epochs), batch_size=min(128, len(data) // 2))
    if epochs == 0:
        model = make_vae(data.cells.shape[1], config)
        params = model.init(jax.random.key(0), jnp.zeros((1, data.cells.shape[1])), jax.random.key(0))["params"]
        return TrainedVAE(model, params, config, data.env, tuple(data.cell_shape), data.fingerprint, [], np.arange(0))
    start = time.perf_counter()
    vae = train_vae(data, config, progress=False)
    part.put("vae_training", {"epochs": epochs, "seconds": round(time.perf_counter() - start, 2), "note": "compilation included"})
    return vae


def decode_timings(part: Part, generators: dict) -> None:
    """Warm milliseconds of one jitted G(z) call per repair and batch of latents (``decode.milliseconds``)."""
    import jax

    from decode import milliseconds

    decode, timings = jax.jit(lambda g, z: g(z)), {}
    for batch in part.sizes["latents"]:
        z = jax.random.normal(jax.random.key(batch), (batch, generators["nearest"].latent_dim))
        for name, generator in generators.items():
            ms = milliseconds(decode, generator, z, part.sizes["decode_calls"])
            timings.setdefault(name, {})[str(batch)] = {"ms_per_call": round(ms, 3), "us_per_world": round(1e3 * ms / batch, 2)}
            print(f"decode {name} {batch}: {ms:.2f} ms", flush=True)
            part.put("decode", timings)


def trained_ppo(part: Part) -> Path:
    """A racing PPO agent: the many-runs section's first, else one trained here at that budget."""
    from worldagent.agents.algorithms import training_config
    from worldagent.agents.distributions import world_distribution
    from worldagent.agents.training import train

    out = part.work / "ppo-agent"
    if not (out / "policy").exists():
        episodes = part.sizes["episodes"]["ppo"]
        pool = world_distribution("racing", "generator", size=part.sizes["pool"], seed=0)
        start = time.perf_counter()
        train("racing", "ppo", training_config("racing", "ppo", episodes=episodes), pool, out, seed=0, progress=False, resume=False)
        part.put("agent", {"algorithm": "ppo", "episodes": episodes, "trained_here_s": round(time.perf_counter() - start, 1)})
    else:
        part.put("agent", {"algorithm": "ppo", "episodes": part.sizes["episodes"]["ppo"], "trained_by": "many_runs"})
    return out


def search_timings(part: Part, generator) -> None:
    """One CMA-ES generation (21 worlds x ``repeats``) and ``eval_worlds`` random worlds x ``repeats``
    with a trained PPO, G(z) included (``search_timing.py``'s measurement)."""
    import numpy as np

    from search_timing import best_time
    from worldagent.experiments import setup
    from worldagent.search.objectives import LatentObjective, Objective
    from worldagent.search.optimisers import make_optimiser

    sizes = part.sizes
    run = setup("racing", str(trained_ppo(part)), generator, repeats=sizes["repeats"])
    objective = LatentObjective(Objective("racing", "reward", False), run.env, run.policy, generator, run.repeats, run.params, keep_worlds=False)
    cmaes = make_optimiser("cmaes", generator.latent_dim, maximize=False, seed=0)

    def generation():
        z = cmaes.ask(cmaes.batch_size)
        cmaes.tell(z, np.array([o.score for o in objective(z, np.arange(len(z)))]))

    part.put("cmaes_generation_s", round(best_time(generation, sizes["timing_repeats"]), 4))
    z = np.random.default_rng(0).standard_normal((sizes["eval_worlds"], generator.latent_dim))
    seconds = best_time(lambda: objective(z, np.arange(len(z))), sizes["timing_repeats"])
    part.put("random_evaluation", {"worlds": sizes["eval_worlds"], "repeats": sizes["repeats"], "seconds": round(seconds, 3)})


def decode_search(part: Part) -> None:
    """A CMA-ES generation and a random evaluation, then G(z) decode timings (both racing repairs): the
    largest decodes last, so a cap that cuts them keeps the rest."""
    generators = racing_generators(part)
    search_timings(part, generators["nearest"])
    decode_timings(part, generators)


SECTIONS = {
    "machine": machine,
    "env_throughput": env_throughput,
    "many_runs": device_runs.many_runs,
    "decode_search": decode_search,
    "quick": device_runs.quick,
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("name", choices=list(SECTIONS))
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--part", type=Path, required=True)
    parser.add_argument("--cap", type=float, default=600.0, help="seconds this section may take (the parent kills it then)")
    parser.add_argument("--smoke", action="store_true")
    args = parser.parse_args()
    part = Part(args.part, args.work, args.smoke, time.time() + args.cap - 2.0)  # 2 s to spare: our results, written first
    part.save()
    SECTIONS[args.name](part)


if __name__ == "__main__":
    main()
