"""Training runs on the host: chunks of jitted updates, checkpoints, learning curves, the saved agent.

``train_racing(config, distribution, out_dir)`` drives an algorithm's jitted ``train_chunk``
a few updates at a time and, between chunks, advances the progress bar, appends the learning
curve (``curve.csv``; ``curve.png`` at the end) and writes a checkpoint (``checkpoint.msgpack``,
the whole training state, atomically). A killed run started again on the same ``out_dir`` with
``resume=True`` continues from its last checkpoint, and ends where the uninterrupted run would
have. At the end the agent is saved to ``out_dir/policy`` (``policy.save_policy``).

Algorithms are a table (``ALGORITHMS``) from name to an ``Algorithm``: its config class and its
``make_train(config, env, env_params, distribution)``, which returns an object with ``init``,
``train_chunk``, ``done`` and ``network`` like ``ppo.Trainer``, whose state has ``params``,
``update``, ``episodes`` and ``env_steps``. ACKTR registers itself with ``register_algorithm``.
"""

from __future__ import annotations

import csv
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import flax.serialization
import jax
import numpy as np

from worldagent.agents import ppo
from worldagent.agents.policy import SavedPolicy, load_policy, save_policy
from worldagent.errors import WorldagentError
from worldagent.files import write_atomically, write_bytes
from worldagent.progress import progress_bar

CHECKPOINT_FILE = "checkpoint.msgpack"
RUN_FILE = "run.json"
CURVE_FILE = "curve.csv"


@dataclass(frozen=True)
class Algorithm:
    """A training algorithm the host loop can drive.

    Attributes:
        name: "ppo", "acktr", ...
        config_type: its frozen config dataclass (with ``to_dict``; ``total_episodes`` field).
        make_train: ``make_train(config, env, env_params, distribution) -> trainer``.
        network_kind: the saved agent's architecture name (``networks.NETWORKS``).
    """

    name: str
    config_type: type
    make_train: Callable
    network_kind: str = "actor_critic"


ALGORITHMS: dict[str, Algorithm] = {"ppo": Algorithm("ppo", ppo.PPOConfig, ppo.make_train)}


def register_algorithm(algorithm: Algorithm) -> None:
    """Add an algorithm to ``ALGORITHMS`` (e.g. ACKTR)."""
    ALGORITHMS[algorithm.name] = algorithm


def get_algorithm(name: str) -> Algorithm:
    """The algorithm called ``name``; unknown names are refused with the known ones."""
    if name not in ALGORITHMS:
        raise WorldagentError(f"unknown algorithm {name!r}; use one of: {', '.join(sorted(ALGORITHMS))}.")
    return ALGORITHMS[name]


@dataclass(frozen=True)
class TrainResult:
    """What a training run produced.

    Attributes:
        agent: the trained agent as saved and reloaded (``policy.SavedPolicy``).
        out_dir: the run directory.
        curve: per-update learning curve, one f[U] array per ``ppo.CURVE_FIELDS`` entry plus
            "update" and "wall_seconds" (only updates that ran).
        episodes: episodes trained.
        env_steps: env steps taken.
        wall_seconds: training time of this call (compilation included), without evaluation.
        resumed_from_update: the checkpoint's update count when resumed, else None.
    """

    agent: SavedPolicy
    out_dir: Path
    curve: dict[str, np.ndarray]
    episodes: int
    env_steps: int
    wall_seconds: float
    resumed_from_update: int | None


def _versions() -> dict:
    import flax
    import optax

    import worldagent

    return {"worldagent": getattr(worldagent, "__version__", "?"), "jax": jax.__version__, "flax": flax.__version__, "optax": optax.__version__}


def _read_curve(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with open(path, newline="") as handle:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(handle)]


def _write_curve(path: Path, rows: list[dict]) -> None:
    fields = ["update", "wall_seconds", *ppo.CURVE_FIELDS]

    def save(tmp: Path) -> None:
        with open(tmp, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=fields)
            writer.writeheader()
            writer.writerows(rows)

    write_atomically(path, save)


def plot_curve(rows: list[dict], path: Path) -> Path:
    """Learning curve figure: mean raw return, crash rate and lap rate against episodes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    episodes = np.array([r["episodes"] for r in rows])
    fig, (ax_return, ax_rate) = plt.subplots(1, 2, figsize=(10, 3.5))
    ax_return.plot(episodes, [r["return"] for r in rows])
    ax_return.set(xlabel="episodes", ylabel="mean episode return (raw)")
    ax_rate.plot(episodes, [r["crashed"] for r in rows], label="crash rate")
    ax_rate.plot(episodes, [r["lap_completed"] for r in rows], label="lap rate")
    ax_rate.set(xlabel="episodes", ylim=(0, 1))
    ax_rate.legend()
    fig.tight_layout()
    write_atomically(path, lambda tmp: fig.savefig(tmp, dpi=100, format="png"))
    plt.close(fig)
    return path


def train_racing(
    config: Any,
    distribution: Any,
    out_dir: str | Path,
    algo: str = "ppo",
    *,
    seed: int = 0,
    env: Any = None,
    env_params: Any = None,
    progress: bool = True,
    resume: bool = True,
    chunk_updates: int = 10,
    distribution_spec: str = "",
    stop_after_chunks: int | None = None,
) -> TrainResult:
    """Train a racing agent on a world distribution, with checkpoints and a learning curve.

    Args:
        config: the algorithm's config (e.g. ``ppo.PPOConfig``).
        distribution: a world distribution (``distributions.world_distribution``).
        out_dir: run directory: ``run.json``, ``checkpoint.msgpack``, ``curve.csv``,
            ``curve.png`` and, at the end, the agent in ``policy/``.
        algo: a name in ``ALGORITHMS`` ("ppo").
        seed: the run's seed (becomes the PRNG key here).
        env, env_params: default ``ParticleRacing()`` and its default params (the config's
            ``respawn`` sets respawn-on-crash for training, see ``ppo.training_params``).
        progress: show a progress bar (episodes).
        resume: continue from ``out_dir``'s checkpoint if there is one (it must be the same
            algorithm, config and seed); otherwise start afresh (overwriting it).
        chunk_updates: updates per jitted chunk (a checkpoint after each).
        distribution_spec: how the distribution was built, recorded in ``run.json``.
        stop_after_chunks: stop after this many chunks even if the budget is not spent (a
            time-boxed run; the checkpoint lets a later call finish it). The agent saved is
            then the snapshot at the stop.

    Returns:
        ``TrainResult``.
    """
    from worldagent.envs.racing.env import ParticleRacing

    algorithm = get_algorithm(algo)
    if not isinstance(config, algorithm.config_type):
        raise WorldagentError(f"algorithm {algo!r} takes a {algorithm.config_type.__name__}, not a {type(config).__name__}.")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise WorldagentError(f"seed={seed!r}; pass a non-negative integer.")
    if chunk_updates < 1:
        raise WorldagentError(f"chunk_updates={chunk_updates}; use at least 1.")
    env = ParticleRacing() if env is None else env
    env_params = env.default_params if env_params is None else env_params
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    run = {
        "algorithm": algo,
        "env": "racing",
        "seed": int(seed),
        "config": config.to_dict(),
        "distribution": distribution_spec,
        "versions": _versions(),
        "device": str(jax.devices()[0].device_kind),
    }
    trainer = algorithm.make_train(config, env, env_params, distribution)
    state = trainer.init(jax.random.key(seed))
    rows: list[dict] = []
    resumed_from = None
    checkpoint = out_dir / CHECKPOINT_FILE
    if resume and checkpoint.is_file():
        try:
            previous = json.loads((out_dir / RUN_FILE).read_text())
        except (OSError, ValueError):
            raise WorldagentError(f"{out_dir} has a checkpoint but no readable {RUN_FILE}; start afresh with resume=False (--no-resume).") from None
        for field in ("algorithm", "seed", "config"):
            if previous.get(field) != run[field]:
                raise WorldagentError(
                    f"{out_dir} holds a run with another {field} ({previous.get(field)!r}); use another output directory or resume=False (--no-resume)."
                )
        try:
            state = flax.serialization.from_bytes(state, checkpoint.read_bytes())
        except Exception:  # corrupt or foreign msgpack
            raise WorldagentError(
                f"checkpoint {checkpoint} is corrupted or from another architecture; start afresh with resume=False (--no-resume)."
            ) from None
        rows = _read_curve(out_dir / CURVE_FILE)
        rows = [r for r in rows if r["update"] <= int(state.update)]
        resumed_from = int(state.update)
    write_bytes(out_dir / RUN_FILE, json.dumps(run, indent=1).encode())

    start = time.perf_counter()
    offset = rows[-1]["wall_seconds"] if rows else 0.0
    total = int(config.total_episodes)
    with progress_bar(f"training {algo} on racing", total=total, enabled=progress) as advance:
        advance(min(int(state.episodes), total))
        chunks = 0
        while not bool(trainer.done(state)) and (stop_after_chunks is None or chunks < stop_after_chunks):
            chunks += 1
            before = int(state.episodes)
            state, curve = trainer.train_chunk(state, chunk_updates)
            curve = jax.device_get(curve)
            ran = np.flatnonzero(curve["active"] > 0)
            first = int(state.update) - len(ran)
            elapsed = offset + time.perf_counter() - start
            for n, i in enumerate(ran):
                rows.append({"update": first + n + 1, "wall_seconds": round(elapsed, 3), **{k: float(curve[k][i]) for k in ppo.CURVE_FIELDS}})
            write_bytes(checkpoint, flax.serialization.to_bytes(jax.device_get(state)))
            _write_curve(out_dir / CURVE_FILE, rows)
            last = rows[-1] if rows else {}
            advance(
                min(int(state.episodes), total) - min(before, total),
                ret=last.get("return", float("nan")),
                crash=last.get("crashed", float("nan")),
                lap=last.get("lap_completed", float("nan")),
            )
    wall = time.perf_counter() - start
    if rows:
        plot_curve(rows, out_dir / "curve.png")
    save_policy(
        out_dir / "policy",
        trainer.network,
        state.params,
        kind=algorithm.network_kind,
        algorithm=algo,
        env="racing",
        obs_shape=env.observation_shape,
        num_actions=env.num_actions,
        training=config.to_dict(),
        extra={
            "seed": int(seed),
            "episodes": int(state.episodes),
            "env_steps": int(state.env_steps),
            "updates": int(state.update),
            "distribution": distribution_spec,
        },
    )
    agent = load_policy(out_dir / "policy", env="racing")
    curve_arrays = {k: np.array([r[k] for r in rows]) for k in ["update", "wall_seconds", *ppo.CURVE_FIELDS]}
    return TrainResult(agent, out_dir, curve_arrays, int(state.episodes), int(state.env_steps), wall, resumed_from)
