"""The host driver of every training run: chunks, checkpoints, resume, learning curve, saved agent.

``train(spec, algo, config, distribution, out_dir)`` builds the env from the spec, the
algorithm's trainer (``algorithms.ALGORITHMS``, ``trainer.Trainer``) and runs its jitted
``train_chunk`` a few updates at a time. Between chunks it advances the progress bar (episodes),
appends the learning curve (``curve.csv``; ``curve.png`` at the end) and writes a checkpoint
(``checkpoint.msgpack``, the whole training state with its key, atomically) every
``CHECKPOINT_SECONDS`` and when the loop stops (done, ``stop_after_chunks``, an exception or
Ctrl-C). A killed run started again on the same ``out_dir`` with ``resume=True`` continues
from its last checkpoint and ends where the uninterrupted run would have. At the end the agent is saved to
``out_dir/policy`` (``saved.save_policy``). With ``keep_every=N`` the agent is also kept as it was
each time training passes a multiple of N episodes, in ``out_dir/snapshots/<episodes>/`` (a policy
directory ``--agent`` loads, e.g. for ``worldagent diff`` of two checkpoints).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import flax.serialization
import jax
import numpy as np

from worldagent.agents.algorithms import get_algorithm
from worldagent.agents.loaders import POLICY_DIR
from worldagent.agents.saved import SavedPolicy, load_policy, save_policy
from worldagent.curricula.snapshots import load_snapshots, save_snapshot
from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.files import write_atomically, write_bytes
from worldagent.progress import progress_bar
from worldagent.provenance import device, versions

CHECKPOINT_FILE = "checkpoint.msgpack"
RUN_FILE = "run.json"
CURVE_FILE = "curve.csv"
PLOT_FILE = "curve.png"
CURRICULUM_PLOT_FILE = "curriculum.png"
SNAPSHOTS_DIR = "snapshots"  # out_dir/snapshots/<episodes>/: the agent kept every keep_every episodes
# A DQN state holds its replay buffer (~94 MB for harvest): written after every chunk, it took
# a third of the quick preset's harvest training. A kill loses at most this much training.
CHECKPOINT_SECONDS = 30.0
HOST_FIELDS = ("update", "wall_seconds")  # curve columns the driver adds to the trainer's


@dataclass(frozen=True)
class TrainResult:
    """What a training run produced.

    Attributes:
        agent: the trained agent as saved in ``out_dir/policy`` and reloaded (``saved.SavedPolicy``).
        out_dir: the run directory.
        curve: the learning curve, one f[U] array per column of ``curve.csv`` ("update",
            "wall_seconds" and the algorithm's curve fields), over the updates that ran.
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


def read_curve(path: Path) -> list[dict]:
    """A learning curve's rows (``curve.csv``: its clock adds up across resumes); [] when there is none."""
    if not path.is_file():
        return []
    with open(path, newline="") as handle:
        return [{k: int(float(v)) if k == "update" else float(v) for k, v in row.items()} for row in csv.DictReader(handle)]  # older files wrote 1.0


def _write_curve(path: Path, rows: list[dict]) -> None:
    def save(tmp: Path) -> None:
        with open(tmp, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)

    write_atomically(path, save)


def plotted_metrics(spec, fields) -> list[str]:
    """The curve's columns worth a panel: the main metric (or the raw return) and the highlighted ones."""
    main = spec.metrics.main if spec.metrics.main in fields else "return"
    return [name for name in dict.fromkeys((main, *spec.metrics.highlighted)) if name in fields]


def plot_curve(rows: list[dict], path: Path, spec) -> Path:
    """Learning-curve figure: one panel per ``plotted_metrics`` column against episodes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = plotted_metrics(spec, rows[0]) or ["episodes"]
    episodes = np.array([r["episodes"] for r in rows])
    fig, axes = plt.subplots(1, len(names), figsize=(4.5 * len(names), 3.5), squeeze=False)
    for axis, name in zip(axes[0], names):
        axis.plot(episodes, [r[name] for r in rows])
        axis.set(xlabel="episodes", title=name.replace("_", " "))
    fig.tight_layout()
    write_atomically(path, lambda tmp: fig.savefig(tmp, dpi=100, format="png"))
    plt.close(fig)
    return path


def _check_resumable(out_dir: Path, run: dict) -> None:
    """Refuse a checkpoint of another run (algorithm, env, options, seed, config or world distribution) before compiling."""
    try:
        previous = json.loads((out_dir / RUN_FILE).read_text())
    except (OSError, ValueError):
        raise WorldagentError(f"{out_dir} has a checkpoint but no readable {RUN_FILE}; start afresh with resume=False (--no-resume).") from None
    for field in ("algorithm", "env", "options", "seed", "config", "distribution"):  # a curriculum changes the state's shape
        if previous.get(field) != run[field]:
            raise WorldagentError(
                f"{out_dir} holds a run with another {field} ({previous.get(field)!r}); use another output directory or resume=False (--no-resume)."
            )


def _restore(state: Any, checkpoint: Path) -> Any:
    """The checkpoint's state, shaped like ``state``; other architectures are refused."""
    try:
        restored = flax.serialization.from_bytes(state, checkpoint.read_bytes())
    except Exception:  # noqa: BLE001 - corrupt or foreign msgpack raises many types
        restored = None
    shapes = lambda tree: [np.shape(x) for x in jax.tree_util.tree_leaves(tree)]  # noqa: E731
    if restored is None or shapes(restored) != shapes(state):
        raise WorldagentError(f"checkpoint {checkpoint} is corrupted or from another architecture; start afresh with resume=False (--no-resume).")
    return restored


def _status(spec, row: dict) -> dict:
    """The progress bar's fields: the plotted metrics of the last update."""
    return {name[:12]: row[name] for name in plotted_metrics(spec, row)}


def _save_agent(folder: Path, spec, algorithm, trainer, state, env, config, extra: dict) -> SavedPolicy:
    """Write the trained agent to the policy directory ``folder`` and read it back."""
    if hasattr(config, "act_epsilon"):  # Q-network agents act as they were trained to (see dqn.DQNConfig)
        extra = {**extra, "act_epsilon": float(config.act_epsilon)}
    save_policy(
        folder,
        trainer.network,
        state.params,
        kind=algorithm.network_kind,
        algorithm=algorithm.name,
        env=spec.name,
        obs_shape=tuple(env.observation_shape),
        num_actions=env.num_actions,
        num_agents=getattr(env, "num_agents", 1),
        training=config.to_dict(),
        extra=extra,
    )
    return load_policy(folder, env=spec.name)


def _run_record(spec, algo: str, config, options: dict, seed: int, distribution_spec: str) -> dict:
    """``run.json``: what the run is (JSON-normalised, so a reread record compares equal)."""
    record = {
        "algorithm": algo,
        "env": spec.name,
        "options": options,
        "seed": int(seed),
        "config": config.to_dict(),
        "distribution": distribution_spec,
    }
    return {**json.loads(json.dumps(record)), "versions": versions(), "device": device()}


def _check_inputs(algorithm, config, distribution, seed) -> None:
    if not isinstance(config, algorithm.config_type):
        raise WorldagentError(f"algorithm {algorithm.name!r} takes a {algorithm.config_type.__name__}, not a {type(config).__name__}.")
    if not callable(getattr(distribution, "sample", None)):
        raise WorldagentError("distribution has no sample(key) method; build one with worldagent.agents.distributions.world_distribution.")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise WorldagentError(f"seed={seed!r}; pass a non-negative integer.")


@dataclass
class OpenRun:
    """A run being trained by a host driver (``train`` here, ``many.train_many``): what it is and where it stands.

    Attributes:
        spec, algorithm, config: the env spec, the ``algorithms.Algorithm`` and its config.
        out_dir: the run directory.
        record: ``run.json``'s content.
        env: the env; trainer: its ``trainer.Trainer``.
        state: the training state (fresh, or restored from the checkpoint).
        rows: the learning curve so far (the checkpoint's rows when resumed).
        resumed_from: the checkpoint's update count when resumed, else None.
        wall_offset: seconds the curve had already counted before this call.
        chunk_updates: updates per jitted chunk.
        distribution: what the run draws its worlds from (a distribution or a curriculum).
        checkpointed: the update count the checkpoint file holds (None: no checkpoint yet).
        checkpoint_clock: ``time.perf_counter()`` when it was written (or the run opened).
    """

    spec: Any
    algorithm: Any
    config: Any
    out_dir: Path
    record: dict
    env: Any
    trainer: Any
    state: Any
    rows: list[dict]
    resumed_from: int | None
    wall_offset: float
    chunk_updates: int
    distribution: Any = None
    checkpointed: int | None = None
    checkpoint_clock: float = dataclasses.field(default_factory=time.perf_counter)


def _check_chunk_updates(config, chunk_updates: int | None) -> int:
    """Updates per jitted chunk: ``chunk_updates``, or the config's (``chunk_updates``; DQN: one episode of every env)."""
    chunk_updates = config.chunk_updates if chunk_updates is None else chunk_updates
    if isinstance(chunk_updates, bool) or not isinstance(chunk_updates, (int, np.integer)) or chunk_updates < 1:
        raise WorldagentError(f"chunk_updates={chunk_updates!r}; use at least 1.")
    return int(chunk_updates)


def open_run(
    spec: Any,
    algo: str,
    config: Any,
    distribution: Any,
    out_dir: str | Path,
    *,
    seed: int,
    options: dict | None,
    params: Any,
    resume: bool,
    distribution_spec: str,
    chunk_updates: int | None,
) -> OpenRun:
    """Check a run's inputs, build its trainer, start it (or restore its checkpoint) and write ``run.json`` (see ``train``)."""
    spec, algorithm = registry.get(spec), get_algorithm(algo)
    _check_inputs(algorithm, config, distribution, seed)
    chunk_updates = _check_chunk_updates(config, chunk_updates)
    options = spec.check_options(options)
    out_dir = Path(out_dir)
    record = _run_record(spec, algo, config, options, seed, distribution_spec)
    checkpoint = out_dir / CHECKPOINT_FILE
    resuming = resume and checkpoint.is_file()
    if resuming:
        _check_resumable(out_dir, record)
    env, env_params = spec.make_env(options)
    env_params = env_params if params is None else params
    trainer = algorithm.make_train(config, env, env_params, distribution, spec.training_params)
    state = trainer.init(jax.random.key(seed))
    rows, resumed_from = [], None
    if resuming:
        state = _restore(state, checkpoint)
        resumed_from = int(state.update)
        rows = [r for r in read_curve(out_dir / CURVE_FILE) if r["update"] <= resumed_from]
    out_dir.mkdir(parents=True, exist_ok=True)
    write_bytes(out_dir / RUN_FILE, json.dumps(record, indent=1).encode())
    offset = rows[-1]["wall_seconds"] if rows else 0.0
    return OpenRun(
        spec, algorithm, config, out_dir, record, env, trainer, state, rows, resumed_from, offset, chunk_updates, distribution, resumed_from
    )


def record_chunk(run: OpenRun, state: Any, curve: dict, elapsed: float) -> None:
    """After a chunk: the run's new state, its curve rows (``curve``: the chunk's, on the host) written,
    and its checkpoint when the last is ``CHECKPOINT_SECONDS`` old. A resume drops curve rows past
    the checkpoint, so the curve may run ahead of it."""
    run.state = state
    run.rows += _new_rows(curve, int(state.update), run.wall_offset + elapsed)
    _write_curve(run.out_dir / CURVE_FILE, run.rows)
    save_snapshot(run.out_dir, state, int(state.update))
    if time.perf_counter() - run.checkpoint_clock >= CHECKPOINT_SECONDS:
        checkpoint(run)


def checkpoint(run: OpenRun) -> None:
    """Write the run's state as its checkpoint, unless the checkpoint already holds it."""
    if run.checkpointed != int(run.state.update):
        write_bytes(run.out_dir / CHECKPOINT_FILE, flax.serialization.to_bytes(jax.device_get(run.state)))
        run.checkpointed = int(run.state.update)
    run.checkpoint_clock = time.perf_counter()


def status(run: OpenRun) -> dict:
    """The progress bar's fields: the plotted metrics of the run's last update."""
    return _status(run.spec, run.rows[-1]) if run.rows else {}


def save_run_agent(run: OpenRun, folder: Path) -> SavedPolicy:
    """Save the run's agent as it is now to the policy directory ``folder`` (its episodes, steps, seed recorded)."""
    state = run.state
    extra = {"seed": run.record["seed"], "episodes": int(state.episodes), "env_steps": int(state.env_steps), "updates": int(state.update)}
    extra = {**extra, "distribution": run.record["distribution"], "options": run.record["options"]}
    return _save_agent(folder, run.spec, run.algorithm, run.trainer, state, run.env, run.config, extra)


def keep_snapshot(run: OpenRun, before: int, every: int | None) -> Path | None:
    """After a chunk that took the run from ``before`` episodes past a multiple of ``every``: the agent
    saved to ``out_dir/snapshots/<episodes>/`` (its path), else None."""
    episodes = int(run.state.episodes)
    if not every or episodes // every == before // every:
        return None
    folder = run.out_dir / SNAPSHOTS_DIR / str(episodes)
    save_run_agent(run, folder)
    return folder


def finish_run(run: OpenRun, wall: float) -> TrainResult:
    """Plot the curve, save the agent to ``out_dir/policy`` and say what the run produced."""
    state, rows = run.state, run.rows
    if rows:
        plot_curve(rows, run.out_dir / PLOT_FILE, run.spec)
    _plot_curriculum(run)
    agent = save_run_agent(run, run.out_dir / POLICY_DIR)
    columns = list(rows[0]) if rows else list(HOST_FIELDS)
    curve = {k: np.array([r[k] for r in rows]) for k in columns}
    return TrainResult(agent, run.out_dir, curve, int(state.episodes), int(state.env_steps), wall, run.resumed_from)


def _plot_curriculum(run: OpenRun) -> None:
    """``curriculum.png`` beside the curve, when the run's curriculum kept a buffer."""
    snapshots = load_snapshots(run.out_dir)
    if snapshots:
        from worldagent.reports.curriculum import curriculum_figure

        generator = getattr(getattr(run.distribution, "worlds", None), "generator", None)
        target = getattr(getattr(run.distribution, "target", None), "text", None)
        title = f"curriculum {getattr(run.distribution, 'name', '')}" + (f", target {target}" if target else "")
        curriculum_figure(snapshots, run.spec, generator, run.out_dir / CURRICULUM_PLOT_FILE, title=title)


def train(
    spec: Any,
    algo: str,
    config: Any,
    distribution: Any,
    out_dir: str | Path,
    *,
    seed: int = 0,
    options: dict | None = None,
    params: Any = None,
    progress: bool = True,
    resume: bool = True,
    distribution_spec: str = "",
    stop_after_chunks: int | None = None,
    chunk_updates: int | None = None,
    keep_every: int | None = None,
) -> TrainResult:
    """Train an agent on a world distribution, with checkpoints, a learning curve and the saved agent.

    Args:
        spec: the environment (an ``EnvSpec`` or its name); the env is ``spec.make_env(options)``.
        algo: a name in ``algorithms.ALGORITHMS`` (see ``algorithms.training_config``).
        config: the algorithm's config.
        distribution: a world distribution (``distributions.world_distribution``) or a
            curriculum (``curricula.make_curriculum``).
        out_dir: run directory: ``run.json``, ``checkpoint.msgpack``, ``curve.csv``,
            ``curve.png`` and, at the end, the agent in ``policy/``; with a curriculum that keeps
            a buffer, its snapshot at every checkpoint (``curriculum/``) and ``curriculum.png``.
        seed: the run's seed (becomes the PRNG key here).
        options: the env's options (e.g. harvest ``{"tagger": (0,)}``).
        params: the env params to train under (default: those ``spec.make_env(options)`` gives);
            an experiment passes the params it evaluates with, so both see the same env. The
            trainer applies ``spec.training_params`` to them (racing: respawn, crash warm-up).
        progress: show a progress bar (episodes).
        resume: continue from ``out_dir``'s checkpoint if there is one (it must be the same
            algorithm, env, options, config and seed); otherwise start afresh (overwriting it).
        distribution_spec: how the distribution was built, recorded in ``run.json``.
        stop_after_chunks: stop after this many chunks even if the budget is not spent (a
            time-boxed run; the checkpoint lets a later call finish it). The agent saved is
            then the snapshot at the stop.
        chunk_updates: updates per jitted chunk, the curve written after each (default: the
            config's ``chunk_updates``; DQN: one episode of every env); the checkpoint every
            ``CHECKPOINT_SECONDS`` and at the stop.
        keep_every: also keep the agent each time training passes a multiple of this many
            episodes, in ``out_dir/snapshots/<episodes>/`` (``<episodes>``: the count at the end of
            that chunk, so a multiple or just past one); None keeps only the final agent.

    Returns:
        ``TrainResult``.
    """
    if keep_every is not None and (isinstance(keep_every, bool) or not isinstance(keep_every, (int, np.integer)) or keep_every < 1):
        raise WorldagentError(f"keep_every={keep_every!r}; pass a positive number of episodes (e.g. half the training budget), or None.")
    run = open_run(
        spec, algo, config, distribution, out_dir, seed=seed, options=options, params=params, resume=resume,
        distribution_spec=distribution_spec, chunk_updates=chunk_updates,
    )  # fmt: skip
    total = int(run.config.episodes)
    with progress_bar(f"training {algo} on {run.spec.name}", total=total, enabled=progress) as advance:
        advance(min(int(run.state.episodes), total))
        wall = run_chunks(run, stop_after_chunks, advance, keep_every)
    return finish_run(run, wall)


def run_chunks(run: OpenRun, stop_after_chunks: int | None, advance, keep_every: int | None = None) -> float:
    """Train ``run`` chunk by chunk until its budget is spent (or ``stop_after_chunks``), recording each chunk and
    checkpointing at the end; ``advance(episodes, **status)`` after each. Its wall seconds."""
    total, start, chunks = int(run.config.episodes), time.perf_counter(), 0
    try:
        while not bool(run.trainer.done(run.state)) and (stop_after_chunks is None or chunks < stop_after_chunks):
            chunks += 1
            before = int(run.state.episodes)
            state, curve = run.trainer.train_chunk(run.state, run.chunk_updates)
            record_chunk(run, state, jax.device_get(curve), time.perf_counter() - start)
            keep_snapshot(run, before, keep_every)
            advance(min(int(state.episodes), total) - min(before, total), **status(run))
    finally:
        checkpoint(run)
    return time.perf_counter() - start


def _new_rows(curve: dict, update: int, elapsed: float) -> list[dict]:
    """Curve rows of the updates of a chunk that ran (``active``), numbered up to ``update``."""
    ran = np.flatnonzero(np.asarray(curve["active"]) > 0)
    first = update - len(ran)
    return [{"update": first + n + 1, "wall_seconds": round(elapsed, 3), **{k: float(v[i]) for k, v in curve.items()}} for n, i in enumerate(ran)]
