"""The host side of independent DQN on Resource Harvest (paper §5.3, §6.2.2).

``train_harvest`` runs ``dqn.make_trainer``'s jitted chunks (one episode of every parallel env
each) with a progress bar, a learning curve (``curve.csv``/``curve.png``), msgpack checkpoints
that a killed run resumes from, and the trained agents saved at the end (``save_agents``;
``load_agents`` reads them back as a policy ``act(params, obs[4, ...], key) -> actions[4]``).
``evaluate`` measures any harvest policy on a batch of worlds (group reward, equality,
conflict, ...), e.g. trained agents against random ones on the same worlds.
"""

from __future__ import annotations

import dataclasses
import functools
import io
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from flax import serialization

from worldagent.agents.dqn import DQNConfig, check_algorithm, chunk_key, make_act, make_trainer, q_network
from worldagent.envs.core import rollout
from worldagent.envs.harvest.env import NUM_ACTIONS, NUM_AGENTS
from worldagent.errors import WorldagentError
from worldagent.files import write_bytes


class TrainResult(NamedTuple):
    """What ``train_harvest`` returns.

    Attributes:
        params: the four agents' Q-network parameters, stacked [4, ...] (policy params of ``make_act``).
        config: the run's ``DQNConfig``.
        history: one dict per chunk (the rows of ``curve.csv``).
        wall_s: training seconds (this call's, plus those of the run it resumed).
        env_steps: env steps trained (4 agent-steps each).
        resumed_chunks: chunks loaded from a checkpoint (0 for a fresh run).
    """

    params: Any
    config: DQNConfig
    history: list
    wall_s: float
    env_steps: int
    resumed_chunks: int


def config_to_dict(config: DQNConfig) -> dict:
    """JSON-able form of a config."""
    return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(config).items()}


def config_from_dict(data: dict) -> DQNConfig:
    """Inverse of ``config_to_dict``; unknown fields are refused."""
    known = {f.name for f in dataclasses.fields(DQNConfig)}
    if not isinstance(data, dict) or set(data) - known:
        raise WorldagentError(
            f"DQN config has unknown fields {sorted(set(data) - known) if isinstance(data, dict) else data!r}; it was saved by another version of worldagent."
        )
    return DQNConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})


def _restore(template: Any, blob: bytes, what: str, remedy: str) -> Any:
    """``flax.serialization.from_bytes`` that refuses other architectures with a one-line error."""

    try:
        restored = serialization.from_bytes(template, blob)
    except Exception as error:  # noqa: BLE001 - any decoding failure is a bad file
        raise WorldagentError(f"{what} does not match this network ({type(error).__name__}); {remedy}.") from None
    want = [(jnp.shape(x), jnp.result_type(x)) for x in jax.tree_util.tree_leaves(template)]
    got = [(jnp.shape(x), jnp.result_type(x)) for x in jax.tree_util.tree_leaves(restored)]
    if want != got:
        raise WorldagentError(f"{what} holds arrays of another architecture; {remedy}.")
    return restored


def save_agents(directory, params: Any, config: DQNConfig, extra: dict | None = None) -> Path:
    """Write the trained agents with ``policy.save_policy`` (``policy.msgpack`` + ``policy.json``):
    the four Q-networks stacked on the agent axis, architecture "q_network", the run's config."""
    from worldagent.agents.policy import save_policy

    return save_policy(
        directory,
        q_network(config),
        params,
        kind="q_network",
        algorithm="dqn",
        env="harvest",
        obs_shape=config.env().observation_shape,
        num_actions=NUM_ACTIONS,
        num_agents=NUM_AGENTS,
        training=config_to_dict(config),
        extra=extra,
    )


def load_agents(directory, epsilon: float | None = None) -> tuple[Callable, Any, DQNConfig]:
    """Read agents written by ``save_agents``: ``(act, params, config)``.

    ``act(params, obs uint8[4, V, V, 4] (or [..., 4, V, V, 4]), key) -> int32[4]`` is
    epsilon-greedy with ``epsilon`` (default: the config's ``act_epsilon``; 0 is greedy).
    Other algorithms, envs and architectures are refused.
    """
    from worldagent.agents.policy import load_policy

    saved = load_policy(directory, env="harvest", algorithm="dqn")
    config = config_from_dict(saved.training)
    if saved.module != q_network(config) or saved.num_agents != NUM_AGENTS:
        raise WorldagentError(
            f"{directory} holds a network of another architecture than its training config says; retrain it with `worldagent train harvest`."
        )
    return make_act(config, epsilon), saved.params, config


def _versions() -> dict:
    import flax
    import optax

    import worldagent

    return {"worldagent": getattr(worldagent, "__version__", "?"), "jax": jax.__version__, "flax": flax.__version__, "optax": optax.__version__}


def json_dumps(data: Any) -> bytes:

    return (json.dumps(data, indent=1) + "\n").encode()


CURVE_FIELDS = (
    "chunk",
    "episodes",
    "env_steps",
    "wall_s",
    "epsilon",
    "group_reward",
    "equality",
    "conflict",
    "return_0",
    "return_1",
    "return_2",
    "return_3",
    "loss",
    "q",
)


def _history_row(config: DQNConfig, index: int, wall: float, stats: dict) -> dict:
    stats = jax.device_get(stats)
    returns = stats["returns"].mean(axis=0)
    row = {
        "chunk": index + 1,
        "episodes": (index + 1) * config.num_envs,
        "env_steps": (index + 1) * config.num_envs * config.episode_length,
        "wall_s": round(wall, 2),
        "epsilon": float(stats["epsilon"]),
    }
    for name in ("group_reward", "equality", "conflict"):
        row[name] = float(stats[name].mean())
    row.update({f"return_{i}": float(returns[i]) for i in range(NUM_AGENTS)})
    row["loss"], row["q"] = float(jnp.nanmean(stats["loss"])), float(jnp.nanmean(stats["q"]))
    return row


def write_curve(directory, history: list, picture: bool = True) -> None:
    """``curve.csv`` (one row per chunk) and, with ``picture``, ``curve.png`` (group reward, equality, conflict by episode)."""

    directory = Path(directory)
    text = io.StringIO()
    text.write(",".join(CURVE_FIELDS) + "\n")
    for row in history:
        text.write(",".join(f"{row[k]:.6g}" if isinstance(row[k], float) else str(row[k]) for k in CURVE_FIELDS) + "\n")
    write_bytes(directory / "curve.csv", text.getvalue().encode())
    if not history or not picture:
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    episodes = [row["episodes"] for row in history]
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.2))
    for ax, name in zip(axes, ("group_reward", "equality", "conflict")):
        ax.plot(episodes, [row[name] for row in history])
        ax.set_xlabel("episodes per agent")
        ax.set_title(name.replace("_", " "))
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=90)
    plt.close(fig)
    write_bytes(directory / "curve.png", buffer.getvalue())


def train_harvest(config: DQNConfig, distribution: Any, out_dir=None, progress: bool = True, resume: bool = True, algo: str = "dqn") -> TrainResult:
    """Train the four harvest agents on worlds drawn from ``distribution`` (paper §5.3).

    Runs ``config.num_chunks`` jitted chunks (one episode of each of ``num_envs`` envs each),
    with a progress bar (running group reward). With ``out_dir`` it writes ``config.json``,
    ``curve.csv``/``curve.png``, a checkpoint (``checkpoint.msgpack`` + ``.json``) every
    ``config.checkpoint_every`` chunks (with the seed, package versions and device) and the
    agents at the end (``out_dir/agents``, ``save_agents``; readable by ``load_agents`` and
    ``policy.load_policy``); a killed
    run called again with the same config and distribution resumes from its last checkpoint
    (pass the same distribution: it is not stored).

    Args:
        config: the run's settings; ``config.seed`` becomes the run's key here.
        distribution: a world distribution (``WorldPool`` of ``HarvestMap`` s, or any pytree with
            ``sample(key) -> HarvestMap``).
        algo: "dqn" (the paper's independent DQN); anything else is refused.

    Returns:
        ``TrainResult``.
    """

    from worldagent.progress import progress_bar

    check_algorithm(algo)
    if not isinstance(config, DQNConfig):
        raise WorldagentError(f"config is a {type(config).__name__}; pass a DQNConfig for algorithm 'dqn'.")
    config.validate()
    if not callable(getattr(distribution, "sample", None)):
        raise WorldagentError("distribution has no sample(key) method; build one with worldagent.agents.distributions (e.g. WorldPool.create(maps)).")
    out = Path(out_dir) if out_dir is not None else None
    resuming = out is not None and resume and (out / "checkpoint.json").is_file()
    if resuming:  # refuse another run's directory before compiling anything
        saved, wanted = json.loads((out / "config.json").read_text()), config_to_dict(config)
        if saved != wanted:
            changed = sorted(k for k in saved.keys() | wanted.keys() if saved.get(k) != wanted.get(k))
            raise WorldagentError(
                f"{out} holds a run with other settings ({', '.join(changed)}); pass the same config, resume=False, or another out_dir."
            )
    trainer = make_trainer(config)
    key_init, key_chunks = jax.random.split(jax.random.key(config.seed))
    state = trainer.init(key_init, distribution)
    history, done, wall_before = [], 0, 0.0
    if resuming:
        meta = json.loads((out / "checkpoint.json").read_text())
        state = _restore(state, (out / "checkpoint.msgpack").read_bytes(), f"checkpoint in {out}", "pass resume=False or another out_dir")
        history, done, wall_before = meta["history"], meta["chunks_done"], meta["wall_s"]
        if int(state.steps) != done * config.episode_length:
            raise WorldagentError(f"checkpoint in {out} is inconsistent (corrupt or half-written); pass resume=False or another out_dir.")
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        write_bytes(out / "config.json", json_dumps(config_to_dict(config)))

    def save_checkpoint(wall: float) -> None:
        write_bytes(out / "checkpoint.msgpack", serialization.to_bytes(jax.device_get(state)))
        write_bytes(
            out / "checkpoint.json",
            json_dumps(
                {
                    "chunks_done": done,
                    "wall_s": wall,
                    "seed": config.seed,
                    "versions": _versions(),
                    "device": str(jax.devices()[0].device_kind),
                    "history": history,
                }
            ),
        )
        write_curve(out, history, picture=done == config.num_chunks)

    resumed = done
    start = time.perf_counter()
    with progress_bar("training harvest agents (episodes)", config.num_chunks * config.num_envs, progress) as advance:
        advance(done * config.num_envs)
        while done < config.num_chunks:
            state, stats = trainer.chunk(chunk_key(key_chunks, done), state, distribution)
            wall = wall_before + time.perf_counter() - start
            history.append(_history_row(config, done, wall, stats))
            done += 1
            advance(config.num_envs, group_reward=history[-1]["group_reward"], epsilon=history[-1]["epsilon"])
            if out is not None and (done % config.checkpoint_every == 0 or done == config.num_chunks):
                save_checkpoint(wall)
    wall = wall_before + time.perf_counter() - start
    if out is not None:
        save_agents(
            out / "agents",
            state.params,
            config,
            extra={
                "act_epsilon": config.act_epsilon,
                "episodes": config.num_chunks * config.num_envs,
                "env_steps": config.num_chunks * config.num_envs * config.episode_length,
                "seed": config.seed,
            },
        )
    env_steps = config.num_chunks * config.num_envs * config.episode_length
    return TrainResult(jax.device_get(state.params), config, history, wall, env_steps, resumed)


def evaluate(key: jax.Array, act: Callable, policy_params: Any, worlds: Any, config: DQNConfig, repeats: int = 1) -> dict[str, jax.Array]:
    """Per-episode harvest metrics of ``act`` on each world (one jitted ``vmap(vmap(scan))``).

    Args:
        act: a policy ``act(policy_params, obs uint8[4, V, V, 4], key) -> int32[4]``.
        worlds: a batch of ``HarvestMap`` (leading axis B).
        config: gives the env, its window, episode length and who may TAG.

    Returns:
        ``env.metrics`` of every episode: ``returns`` f32[B, repeats, 4] and f32[B, repeats]
        ``group_reward``, ``equality``, ``conflict``, ``sustainability``, ``peace``.
    """

    return _evaluator(act, config, repeats)(key, policy_params, worlds)


@functools.lru_cache(maxsize=32)
def _evaluator(act: Callable, config: DQNConfig, repeats: int) -> Callable:
    env, env_params = config.env(), config.env_params()

    @jax.jit
    def run(key, policy_params, worlds):
        def one(key, world):
            policy = lambda k, obs, state: act(policy_params, obs, k)  # noqa: E731
            final, _ = rollout(env, policy, key, world, env_params, config.episode_length)
            return env.metrics(final)

        num_worlds = jax.tree_util.tree_leaves(worlds)[0].shape[0]
        keys = jax.random.split(key, (num_worlds, repeats))
        return jax.vmap(lambda ks, w: jax.vmap(lambda k: one(k, w))(ks))(keys, worlds)

    return run
