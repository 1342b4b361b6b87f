"""Environments at the same time: one manifest written by several processes, a failing env beside a finishing one,
how many at once, and one env's progress bars at a time. No JAX: the processes run stand-in phases."""

from __future__ import annotations

import multiprocessing
import threading

import pytest

from worldagent.errors import WorldagentError
from worldagent.reproduce.manifest import Manifest
from worldagent.reproduce.phases import CURRICULUM_DEPENDS, DEPENDS
from worldagent.reproduce.pipeline import (
    CHAINS,
    EnvFailed,
    Task,
    bars_for_phase,
    chain_needs,
    concurrent_envs,
    finished,
    next_tasks,
    one_thread_flags,
    run_env_processes,
)
from worldagent.reproduce.presets import PHASES

STEPS = 25  # phases each stand-in env records: enough writes for unlocked read-modify-writes to lose some
STAND_IN = tuple(f"phase{step}" for step in range(STEPS))


def record_phases(manifest, preset, out, env, progress, say, bars, phases) -> None:
    """A stand-in task: ``phases`` started and finished, one status line each; env "broken" fails at phase2."""
    for phase in phases:
        key = f"{env}/{phase}"
        manifest.start(key, {"phase": phase})
        if env == "broken" and phase == "phase2":
            manifest.fail(key, WorldagentError("no world has the property"))
            raise WorldagentError("no world has the property; raise --candidates.")
        manifest.finish(key, {"summary": phase})
        say(f"{key}: done")


def write_phases(out: str, env: str) -> None:
    """One process's many changes to the shared manifest, each on its own keys."""
    manifest = Manifest.open(out)
    for step in range(STEPS):
        manifest.start(f"{env}/phase{step}", {"step": step})
        manifest.finish(f"{env}/phase{step}", {"step": step})


def test_two_processes_writing_the_manifest_lose_nothing(tmp_path):
    Manifest.open(tmp_path).begin_run("tiny", {"seed": 0}, ["a", "b"])
    context = multiprocessing.get_context("spawn")
    processes = [context.Process(target=write_phases, args=(str(tmp_path), env)) for env in ("a", "b")]
    for process in processes:
        process.start()
    for process in processes:
        process.join(60)
        assert process.exitcode == 0
    phases = Manifest.open(tmp_path).data["phases"]
    assert sorted(phases) == sorted(f"{env}/phase{step}" for env in ("a", "b") for step in range(STEPS))
    assert all(entry["status"] == "done" for entry in phases.values())
    assert Manifest.open(tmp_path).data["runs"][0]["envs"] == ["a", "b"]  # the parent's record survives its children's writes


def test_a_failing_env_leaves_the_other_envs_phases_done(tmp_path):
    Manifest.open(tmp_path).begin_run("tiny", {"seed": 0}, ["broken", "fine"])
    lines: list[str] = []
    tasks = [
        Task("broken", STAND_IN, ()),
        Task("fine", STAND_IN, ()),
        Task("fine", ("later",), ("fine/phase24",)),  # starts once the first fine task's last phase is done
        Task("broken", ("later",), ("broken/phase24",)),  # never ready: broken stopped at phase2
    ]
    said = r"^broken: no world has the property; raise --candidates\.; later not run: broken/phase24 did not finish$"
    with pytest.raises(EnvFailed, match=said):
        run_env_processes(None, tmp_path, tasks, 2, False, lines.append, work=record_phases)  # stand-ins: no preset
    phases = Manifest.open(tmp_path).data["phases"]
    assert [phases[f"fine/{phase}"]["status"] for phase in (*STAND_IN, "later")] == ["done"] * (STEPS + 1)
    assert [phases[f"broken/phase{step}"]["status"] for step in range(3)] == ["done", "done", "failed"]
    assert "broken/phase3" not in phases and "broken/later" not in phases
    assert phases["fine/later"]["started"] >= phases["fine/phase24"]["finished"]
    assert "fine/phase24: done" in lines and "broken/phase1: done" in lines  # every process's lines reach the parent's echo


def test_each_envs_chains_cover_its_phases_and_wait_for_what_they_are_computed_from():
    assert sorted(phase for chain in CHAINS for phase in chain) == sorted(PHASES)
    assert all(list(chain) == [p for p in PHASES if p in chain] for chain in CHAINS)  # each in pipeline order
    training, evaluating = CHAINS
    assert chain_needs(training, DEPENDS) == () and chain_needs(training, CURRICULUM_DEPENDS) == ()
    assert chain_needs(evaluating, DEPENDS) == ("generator", "agent")
    assert chain_needs(("strategic", "atlas"), DEPENDS) == ("generator", "agent", "random")


def test_envs_run_one_per_core_on_a_cpu_and_one_at_a_time_otherwise():
    assert concurrent_envs(3, 2, "cpu", sequential=False, can_share=True) == 2
    assert concurrent_envs(2, 16, "cpu", sequential=False, can_share=True) == 2
    assert concurrent_envs(1, 16, "cpu", sequential=False, can_share=True) == 1
    assert concurrent_envs(2, 16, "cpu", sequential=True, can_share=True) == 1
    assert concurrent_envs(2, 16, "gpu", sequential=False, can_share=True) == 1  # each process would claim the device
    assert concurrent_envs(2, 16, "cpu", sequential=False, can_share=False) == 1  # no flock: one manifest writer


def test_env_processes_compute_on_one_thread_unless_the_users_flags_say_otherwise():
    assert one_thread_flags("") == "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
    assert one_thread_flags("--xla_force_host_platform_device_count=2") == (
        "--xla_force_host_platform_device_count=2 --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
    )
    assert one_thread_flags("--xla_cpu_multi_thread_eigen=true") == "--xla_cpu_multi_thread_eigen=true intra_op_parallelism_threads=1"


def test_one_env_shows_its_progress_bars_at_a_time():
    token = threading.Lock()
    with bars_for_phase(True, token) as first:
        with bars_for_phase(True, token) as second:
            assert (first, second) == (True, False)
    with bars_for_phase(True, token) as freed:
        assert freed  # released when the phase ended
    with bars_for_phase(False, token) as quiet, bars_for_phase(True, None) as alone:
        assert (quiet, alone) == (False, True)


def test_the_env_with_most_phases_left_starts_first_once_ready():
    evaluations = [Task(env, CHAINS[1], (f"{env}/generator", f"{env}/agent")) for env in ("racing", "harvest")]
    trained = {f"{env}/{phase}": {"status": "done"} for env in ("racing", "harvest") for phase in CHAINS[0][:3]}
    racing_done = {**trained, "racing/influence": {"status": "done"}}  # harvest still influences: it is behind, its evaluations go first
    assert [task.env for task in next_tasks(evaluations, racing_done, 1)] == ["harvest"]
    assert [task.env for task in next_tasks(evaluations, racing_done, 2)] == ["harvest", "racing"]
    assert next_tasks(evaluations, {}, 2) == []  # no agent trained yet: nothing is ready
    assert [task.env for task in next_tasks(evaluations, trained, 2)] == ["racing", "harvest"]  # a tie keeps the order


class NamedConfigs:
    """A stand-in preset: each phase's config is its name (and ``extra``)."""

    def __init__(self, extra: int = 0):
        self.extra = extra

    def phase_config(self, env: str, phase: str) -> dict:
        return {"phase": phase, "extra": self.extra}


def test_a_chain_whose_phases_are_all_done_starts_no_process(tmp_path):
    manifest = Manifest.open(tmp_path)
    for phase in ("a", "b"):
        manifest.start(f"x/{phase}", NamedConfigs().phase_config("x", phase))
        manifest.finish(f"x/{phase}", {})
    assert finished(Task("x", ("a", "b"), ()), manifest, NamedConfigs())
    assert not finished(Task("x", ("a", "b", "c"), ()), manifest, NamedConfigs())  # c never ran
    with pytest.raises(WorldagentError, match="another config"):
        finished(Task("x", ("a",), ()), manifest, NamedConfigs(extra=1))
