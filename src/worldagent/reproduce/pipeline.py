"""``reproduce``: the paper end to end, phase by phase, cached in a run directory.

For each environment the phases of ``phases.PHASE_FUNCTIONS`` run in order (dataset →
generator → agent → random evaluation → strategic min/max → optimiser comparison →
influencing → failure atlas), then the HTML report is built. The manifest (``manifest.py``) records each
phase; a phase already done with the same config is skipped, an unfinished one runs again and
resumes from its own checkpoint or store, and one done with another config is refused until
``restart`` names it (which also restarts every phase computed from it).

The influencing phase is the most likely to find nothing (no world may have the
selected property at a small budget): its failure is recorded in the manifest and the report as
that phase's result, and the run carries on to the report instead of crashing.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable, Iterable
from pathlib import Path

from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.reproduce.manifest import Manifest, phase_key
from worldagent.reproduce.phases import CURRICULUM_DEPENDS, DEPENDS, PHASE_FUNCTIONS, EnvContext, compare_names, dependents
from worldagent.reproduce.presets import PHASES, Preset, paper_phase_config

TOLERATED = ("influence",)  # phases whose failure is a result, not the end of the run


def resolve_envs(env: str, preset: Preset) -> list[str]:
    """``"all"`` → every environment the preset has budgets for; otherwise the one named."""
    if env == "all":
        return list(preset.envs)
    if env not in preset.envs:
        known = ", ".join(preset.envs)
        registry.get(env)  # an unregistered name says so first
        raise WorldagentError(f"{env} has no {preset.name!r} preset; use one of: {known} or all.")
    return [env]


def restart_closure(phases: Iterable[str], curriculum: bool = False) -> list[str]:
    """The phases to redo for ``--restart`` of ``phases`` (with all that depends on them; ``curriculum``:
    the agents train with an adaptive curriculum over G(z), so redoing the generator redoes them)."""
    found = {name for phase in phases for name in dependents(phase, curriculum)}
    return [name for name in PHASES if name in found]


def reproduce(
    preset: Preset, out: Path | str, envs: list[str], restart: Iterable[str] = (), progress: bool = True, echo: Callable[[str], None] = print
) -> Manifest:
    """Run (or resume) the pipeline for ``envs`` in run directory ``out`` and build its report.

    Args:
        preset: budgets and seeds (``presets.PRESETS``).
        out: the run directory (created).
        envs: environments, from ``resolve_envs`` (each with budgets in ``preset``).
        restart: phases to redo from scratch, with everything computed from them.
        progress: show progress bars.
        echo: where the one status line per phase goes.

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
    for env in envs:
        ctx = EnvContext(out, env, preset, progress)
        for phase in PHASES:
            run_phase(
                manifest,
                phase_key(env, phase),
                preset.phase_config(env, phase),
                lambda p=phase: PHASE_FUNCTIONS[p](ctx),
                echo,
                tolerate=phase in TOLERATED,
                about=settings_record(preset, env, phase),
            )
    from worldagent.reports.html import build_report

    run_phase(manifest, "report", {"preset": preset.name}, lambda: report_outputs(build_report(out), out), echo, skip=False)
    return manifest


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

    names = experiments.campaign_names(ctx.metric, ctx.seed)
    found = [names["min"], names["max"]] if "strategic" in phases else []
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
