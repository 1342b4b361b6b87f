"""``reproduce``: the paper end to end, phase by phase, cached in a run directory.

For each environment the phases of ``phases.PHASE_FUNCTIONS`` run in order (dataset →
generator → agent → random evaluation → strategic min/max → optimiser comparison →
influencing → failure atlas), then the HTML report is built. The manifest (``manifest.py``) records each
phase; a phase already done with the same config is skipped, an unfinished one runs again and
resumes from its own checkpoint or store, and one done with another config is refused until
``restart`` names it (which also restarts every phase computed from it).

Environments run at the same time (``envs_at_once`` decides how many processes: one per core on a CPU),
each env's phases as two chains (``CHAINS``: training and influencing; the evaluations, once the agent is
trained), each chain in a process of its own (the env with the most phases left first: ``next_tasks``), all recording into the one manifest; the report waits for them all. The
parent prints every process's status lines (each starts with its env); progress bars are shown by
one env at a time (``bars_for_phase``: a phase takes the token if it is free, else runs without bars),
as two processes drawing bars on one terminal overwrite each other. ``--env NAME`` (one env) runs in
this process, as does every env when ``WORLDAGENT_SEQUENTIAL_ENVS=1`` (``--sequential``) or the
backend is an accelerator (each process would claim its memory).

The influencing phase is the most likely to find nothing (no world may have the
selected property at a small budget): its failure is recorded in the manifest and the report as
that phase's result, and the run carries on to the report instead of crashing.
"""

from __future__ import annotations

import os
import shutil
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from queue import Empty

from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.reproduce.manifest import Manifest, can_share, phase_key
from worldagent.reproduce.phases import CURRICULUM_DEPENDS, DEPENDS, PHASE_FUNCTIONS, EnvContext, compare_names, dependents
from worldagent.reproduce.presets import PHASES, Preset, paper_phase_config
from worldagent.search.optimisers import OPTIMISERS

TOLERATED = ("influence",)  # phases whose failure is a result, not the end of the run
SEQUENTIAL_VARIABLE = "WORLDAGENT_SEQUENTIAL_ENVS"  # set (to anything but "" or "0"): one env after another
# XLA flags of the env processes that share a CPU's cores: each computes on one thread. Eigen's threads in every
# process would contend for the same cores; with one each, two processes at once played harvest's episodes and trained
# its DQN about 11% faster, a VAE's steps as fast (benchmarks/results/concurrent-threads-cpu.json). A flag the user's
# XLA_FLAGS names wins.
ONE_THREAD_FLAGS = ("--xla_cpu_multi_thread_eigen=false", "intra_op_parallelism_threads=1")
PARENT_POLL_S = 1.0  # how often an env's process checks that the run's process is still there
STOP_WAIT_S = 60.0  # after Ctrl-C, how long env processes get to record where they stopped before they are told again


def resolve_envs(env: str, preset: Preset) -> list[str]:
    """``"all"`` → every environment the preset has budgets for; otherwise the ones named (``"racing,harvest"``), in that order."""
    if env == "all":
        return list(preset.envs)
    named = list(dict.fromkeys(name.strip() for name in env.split(",") if name.strip()))
    for name in named or [env]:
        if name not in preset.envs:
            known = ", ".join(preset.envs)
            registry.get(name)  # an unregistered name says so first
            raise WorldagentError(f"{name} has no {preset.name!r} preset; use one of: {known} or all.")
    return named


def restart_closure(phases: Iterable[str], curriculum: bool = False) -> list[str]:
    """The phases to redo for ``--restart`` of ``phases`` (with all that depends on them; ``curriculum``:
    the agents train with an adaptive curriculum over G(z), so redoing the generator redoes them)."""
    found = {name for phase in phases for name in dependents(phase, curriculum)}
    return [name for name in PHASES if name in found]


def reproduce(
    preset: Preset,
    out: Path | str,
    envs: list[str],
    restart: Iterable[str] = (),
    progress: bool = True,
    echo: Callable[[str], None] = print,
    sequential: bool = False,
) -> Manifest:
    """Run (or resume) the pipeline for ``envs`` in run directory ``out`` and build its report.

    Args:
        preset: budgets and seeds (``presets.PRESETS``).
        out: the run directory (created).
        envs: environments, from ``resolve_envs`` (each with budgets in ``preset``).
        restart: phases to redo from scratch, with everything computed from them.
        progress: show progress bars.
        echo: where the one status line per phase goes.
        sequential: run the environments one after another in this process (``envs_at_once``).

    Returns:
        The manifest as it stands at the end.
    """
    out = Path(out)
    late = {env: preset.check_curriculum(env) for env in envs}  # refused in one line before anything is read or written
    manifest = Manifest.open(out)
    redo = restart_closure(restart, adaptive(preset, envs))
    for env in envs:
        forget_phases(manifest, EnvContext(out, env, preset), redo)
    check_configs(manifest, preset, envs)
    for env, warning in late.items():  # once the run is sure to go on
        if warning:
            echo(f"{env}: {warning}")
    out.mkdir(parents=True, exist_ok=True)
    manifest.begin_run(preset.name, preset.to_dict(), envs)
    at_once = envs_at_once(envs, sequential)
    if at_once > 1:
        tasks = env_tasks(preset, envs)
        for task in [task for task in tasks if finished(task, manifest, preset)]:  # said here: no process to start
            run_env(manifest, preset, out, task.env, progress, echo, phases=task.phases)
            tasks.remove(task)
        run_env_processes(preset, out, tasks, at_once, progress, echo)
        manifest = Manifest.open(out)  # with every env's phases, as their processes wrote them
    else:
        for env in envs:
            run_env(manifest, preset, out, env, progress, echo)
    from worldagent.reports.html import build_report

    run_phase(manifest, "report", {"preset": preset.name}, lambda: report_outputs(build_report(out), out), echo, skip=False)
    return manifest


def run_env(
    manifest: Manifest, preset: Preset, out: Path, env: str, progress: bool, echo: Callable[[str], None], bars=None, phases: Iterable[str] = PHASES
) -> None:
    """``phases`` of one environment (default: every one), in order (``bars``: the token of ``bars_for_phase``, None alone)."""
    ctx = EnvContext(out, env, preset, progress)
    for phase in phases:
        with bars_for_phase(progress, bars) as shown:
            ctx.progress = shown
            run_phase(
                manifest,
                phase_key(env, phase),
                preset.phase_config(env, phase),
                lambda p=phase: PHASE_FUNCTIONS[p](ctx),
                echo,
                tolerate=phase in TOLERATED,
                about=settings_record(preset, env, phase),
            )


# -- environments at the same time ----------------------------------------------------------------


def envs_at_once(envs: list[str], sequential: bool = False) -> int:
    """How many processes run environments' phase chains at the same time (the one place this is decided; 1: all in this process)."""
    forced = sequential or os.environ.get(SEQUENTIAL_VARIABLE, "") not in ("", "0")
    return concurrent_envs(len(envs), os.cpu_count() or 1, jax_backend(), forced, can_share())


def concurrent_envs(envs: int, cpus: int, backend: str, sequential: bool, can_share: bool) -> int:
    """``envs_at_once`` from its facts: one process per env up to one per core, on a CPU backend only (on an
    accelerator every process would claim the device's memory), where the manifest can be shared (``fcntl``)."""
    if sequential or backend != "cpu" or not can_share:
        return 1
    return max(1, min(envs, cpus))


def jax_backend() -> str:
    """JAX's default backend here ("cpu", "gpu", ...); this process uses it already (``begin_run`` records the device)."""
    import jax

    return jax.default_backend()


@contextmanager
def bars_for_phase(progress: bool, token) -> Iterator[bool]:
    """Whether a phase shows progress bars: ``progress``, and, beside other envs' processes (``token``: a lock
    they share), only if no other env shows its bars now (two processes' bars on one terminal overwrite each other)."""
    if not progress or token is None:
        yield progress
        return
    held = token.acquire(False)  # positional: threading and multiprocessing locks name it differently
    try:
        yield held
    finally:
        if held:
            token.release()


# Each env's phases in two chains, each in a process of its own once the phases it needs are done: training and
# influencing (two agents trained: the longest phase), and the evaluations beside it once the agent is trained.
CHAINS = (("dataset", "generator", "agent", "influence"), ("random", "strategic", "compare", "atlas"))


@dataclass(frozen=True)
class Task:
    """One chain of one env's phases for a process of its own: ``needs``, the phase keys that must be done first."""

    env: str
    phases: tuple[str, ...]
    needs: tuple[str, ...]


def chain_needs(chain: Iterable[str], depends: dict[str, tuple[str, ...]]) -> tuple[str, ...]:
    """The phases outside ``chain`` that its phases are computed from (what must be done before it starts), in pipeline order."""
    chain = tuple(chain)
    found = {parent for phase in chain for parent in depends[phase]} - set(chain)
    return tuple(name for name in PHASES if name in found)


def env_tasks(preset: Preset, envs: list[str]) -> list[Task]:
    """The tasks of ``envs``: each env's ``CHAINS``, the first chain of every env before any second one."""
    tasks = []
    for chain in CHAINS:
        for env in envs:
            depends = CURRICULUM_DEPENDS if preset.curriculum_of(env) is not None else DEPENDS
            tasks.append(Task(env, chain, tuple(phase_key(env, phase) for phase in chain_needs(chain, depends))))
    return tasks


def finished(task: Task, manifest: Manifest, preset: Preset) -> bool:
    """Whether every phase of ``task`` is done with the preset's config (a rerun only says so)."""
    return all(manifest.is_done(phase_key(task.env, phase), preset.phase_config(task.env, phase)) for phase in task.phases)


def ready(task: Task, phases: dict) -> bool:
    """Whether every phase ``task`` needs is done in the manifest's ``phases``."""
    return all(done(phases, key) for key in task.needs)


def done(phases: dict, key: str) -> bool:
    return (phases.get(key) or {}).get("status") == "done"


def next_tasks(waiting: list[Task], phases: dict, free: int) -> list[Task]:
    """The ``free`` waiting tasks to start now: ready ones, of the env with the most phases not yet done first (the one
    likely to end last; ties in ``waiting``'s order). From the recorded quick run's phase times, racing's and harvest's
    chains end after 1,002 s on 2 cores this way, 1,113 s in ``env_tasks``' order, 1,180 s as one process per env."""
    left = {task.env: sum(not done(phases, phase_key(task.env, phase)) for phase in PHASES) for task in waiting}
    return sorted((task for task in waiting if ready(task, phases)), key=lambda task: -left[task.env])[: max(0, free)]


class EnvFailed(WorldagentError):
    """An environment's process ended without finishing its phases (its own error, or an interrupt)."""


def run_env_processes(
    preset: Preset, out: Path, tasks: list[Task], at_once: int, progress: bool, echo: Callable[[str], None], work: Callable = run_env
) -> None:
    """Run ``tasks`` (``env_tasks``; ``work``: ``run_env``), each in a process of its own (spawned: JAX's state and
    numpy's parser are per process), ``at_once`` at a time, each once the phases it needs are done, each computing on one
    thread (``ONE_THREAD_FLAGS``); status lines are echoed here. A task that fails stops only itself (and what needs it);
    once none can run, the failures are raised as one ``EnvFailed`` (every finished phase is in the manifest). Ctrl-C (or this process's end) stops them all, each
    recording where it stopped, so a rerun resumes."""
    import multiprocessing

    context = multiprocessing.get_context("spawn")
    messages, bars = context.Queue(), context.Lock()
    waiting, running, failures = list(tasks), {}, {}
    try:
        while True:
            phases = Manifest.open(out).data["phases"]
            for task in next_tasks(waiting, phases, at_once - len(running)):
                waiting.remove(task)
                args = (preset, str(out), task.env, progress, messages, bars, os.getpid(), work, task.phases)
                running[task] = context.Process(target=env_process, args=args, name=f"worldagent-reproduce-{task.env}")
                with child_environment("XLA_FLAGS", one_thread_flags(os.environ.get("XLA_FLAGS", ""))):
                    running[task].start()
            if not running:
                break
            relay(messages, echo, failures, wait=0.5)
            for task, process in list(running.items()):
                if not process.is_alive():
                    process.join()
                    relay(messages, echo, failures, wait=0.0)
                    if process.exitcode != 0 and task.env not in failures:
                        note(failures, task.env, f"its process ended with exit code {process.exitcode}")
                    del running[task]
    except BaseException:  # Ctrl-C reached every process of the terminal: let each record where it stopped
        stop_env_processes(running.values())
        relay(messages, echo, failures, wait=0.0)
        raise
    for task in waiting:  # never ready: a phase it needs failed in another task (that failure is said)
        note(failures, task.env, f"{', '.join(task.phases)} not run: {', '.join(task.needs)} did not finish")
    if failures:
        raise EnvFailed("; ".join(f"{env}: {why}" for env, why in failures.items()))


def one_thread_flags(flags: str) -> str:
    """``flags`` (``XLA_FLAGS``) with ``ONE_THREAD_FLAGS`` added where it names none of their settings."""
    named = {flag.split("=")[0].lstrip("-") for flag in flags.split()}
    added = [flag for flag in ONE_THREAD_FLAGS if flag.split("=")[0].lstrip("-") not in named]
    return " ".join([*flags.split(), *added])


@contextmanager
def child_environment(variable: str, value: str) -> Iterator[None]:
    """``os.environ[variable]`` set to ``value`` while processes are spawned (they copy it), then restored."""
    before = os.environ.get(variable)
    os.environ[variable] = value
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(variable, None)
        else:
            os.environ[variable] = before


def relay(messages, echo: Callable[[str], None], failures: dict[str, str], wait: float) -> None:
    """Echo the status lines the env processes sent, and note their failures, waiting up to ``wait`` s for the first."""
    timeout = wait
    while True:
        try:
            kind, env, text = messages.get(timeout=timeout) if timeout > 0 else messages.get_nowait()
        except Empty:
            return
        timeout = 0.0
        if kind == "line":
            echo(text)
        else:
            note(failures, env, text)


def note(failures: dict[str, str], env: str, why: str) -> None:
    """Add ``why`` to what went wrong in ``env`` (its two chains may both fail)."""
    failures[env] = f"{failures[env]}; {why}" if env in failures else why


def stop_env_processes(processes) -> None:
    """Wait for interrupted env processes to record their phases, telling the ones still running again, then ending them."""
    deadline = time.monotonic() + STOP_WAIT_S
    for process in processes:
        process.join(max(0.0, deadline - time.monotonic()))
    for process in processes:
        if process.is_alive():
            os.kill(process.pid, signal.SIGINT)
            process.join(STOP_WAIT_S)
        if process.is_alive():
            process.terminate()
            process.join()


def env_process(
    preset: Preset, out: str, env: str, progress: bool, messages, bars, parent: int, work: Callable = run_env, phases: Iterable[str] = PHASES
) -> None:
    """The body of one task's process: ``work`` (``run_env``) on ``phases`` of ``env``, recorded in the shared manifest;
    status lines and the failure (its one line, or a traceback) go to the parent through ``messages``."""
    watch_parent(parent)
    say = lambda text: messages.put(("line", env, text))  # noqa: E731
    try:
        work(Manifest.open(out), preset, Path(out), env, progress, say, bars, phases)
    except WorldagentError as error:
        messages.put(("failed", env, str(error)))
        sys.exit(1)
    except KeyboardInterrupt:
        messages.put(("failed", env, "interrupted; its phases so far are in the manifest, a rerun resumes"))
        sys.exit(130)
    except BaseException:
        messages.put(("failed", env, traceback.format_exc()))
        sys.exit(1)


def watch_parent(parent: int) -> None:
    """Interrupt this process (as Ctrl-C would) once the run's process is gone (killed): an env's process
    never runs on alone, where a rerun would start a second one on the same files."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL_S)
        os.kill(os.getpid(), signal.SIGINT)

    threading.Thread(target=watch, name="watch-parent", daemon=True).start()


def report_outputs(path: Path, out: Path) -> dict:
    """The report phase's record: where the report is and how big."""
    return {"report": str(path.relative_to(out)), "summary": f"{path} ({path.stat().st_size / 1e6:.1f} MB)"}


def settings_record(preset: Preset, env: str, phase: str) -> dict:
    """What the report reads of a phase beside its config: every setting (defaults written in), the paper preset's
    (None: the env has none) and the phases it is computed from, so the report compares recorded with recorded."""
    depends = CURRICULUM_DEPENDS if preset.curriculum_of(env) is not None else DEPENDS
    return {"full_config": preset.full_phase_config(env, phase), "paper_config": paper_phase_config(env, phase), "depends": list(depends[phase])}


def adaptive(preset: Preset, envs: list[str]) -> bool:
    """Whether the agents of ``envs`` train with an adaptive curriculum (over G(z): the generator's dependents)."""
    return any(preset.curriculum_of(env) is not None for env in envs)


def check_configs(manifest: Manifest, preset: Preset, envs: list[str]) -> None:
    """Refuse, before any work, a phase recorded with a config other than the preset's."""
    for env in envs:
        for phase in PHASES:
            manifest.check_config(phase_key(env, phase), preset.phase_config(env, phase))


def run_phase(
    manifest: Manifest,
    key: str,
    config: dict,
    work: Callable[[], dict],
    echo: Callable[[str], None],
    tolerate: bool = False,
    skip: bool = True,
    about: dict | None = None,
) -> dict:
    """Run one phase unless it is done with ``config``; record it (with ``about``: ``settings_record``); print one status line."""
    if skip and manifest.is_done(key, config):
        echo(f"{key}: done already, skipped ({manifest.phase(key).get('wall_s', 0):.1f} s when it ran)")
        manifest.annotate(key, about)
        return manifest.phase(key)
    manifest.start(key, config, about)
    echo(f"{key}: running")
    start = time.perf_counter()
    try:
        outputs = work()
    except WorldagentError as error:
        entry = manifest.fail(key, error)
        if not tolerate:
            raise
        echo(f"{key}: failed after {time.perf_counter() - start:.1f} s, recorded as the phase's result: {error}")
        return entry
    except BaseException as error:  # KeyboardInterrupt too: the manifest says where the run stopped
        manifest.fail(key, error)
        raise
    entry = manifest.finish(key, outputs)
    echo(f"{key}: done in {entry['wall_s']:.1f} s - {outputs.get('summary', '')}")
    return entry


def forget_phases(manifest: Manifest, ctx: EnvContext, phases: list[str]) -> None:
    """Remove the outputs of ``phases`` of one environment and drop them from the manifest."""
    if not phases:
        return
    layout = ctx.layout
    outputs = layout.phase_outputs()
    for phase in phases:
        for path in outputs.get(phase, []):
            remove(path)
    if "random" in phases:
        for suffix in ("", "-wal", "-shm"):
            remove(Path(f"{layout.store_path}{suffix}"))
    elif layout.store_path.exists():
        from worldagent.store import RunStore

        with RunStore(layout.store_path) as store:
            store.delete_campaigns(store_campaigns(ctx, phases))
    manifest.forget([phase_key(ctx.env, phase) for phase in phases])


def store_campaigns(ctx: EnvContext, phases: list[str]) -> list[str]:
    """Names of the store campaigns written by ``phases``."""
    from worldagent import experiments

    found = []
    if "strategic" in phases:  # whichever optimiser searched them (a preset's optimiser may have changed since)
        found += [name for optimiser in OPTIMISERS for name in experiments.strategic_campaign_names(optimiser, ctx.metric, ctx.seed)]
    if "compare" in phases:
        found += [n for group in compare_names(ctx).values() for n in group]
    if "atlas" in phases:
        from worldagent.analysis.failure_rate import METHODS
        from worldagent.analysis.stored import campaign_name

        found.append(experiments.atlas_campaign_name(False, ctx.metric, ctx.seed))
        if ctx.spec.failure:
            event = experiments.failure_selection(ctx.spec.failure, ctx.env).text
            found += [campaign_name(method, event, ctx.seed) for method in METHODS]
    return found


def remove(path: Path) -> None:
    """Delete a file or directory tree if it exists."""
    if path.is_dir():
        shutil.rmtree(path)
    elif path.exists():
        path.unlink()
