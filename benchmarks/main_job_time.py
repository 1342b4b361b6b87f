"""The main job's time: `worldagent reproduce --preset quick` from nothing, end to end (target: 10 minutes on 2 cores).

    python benchmarks/main_job_time.py [--env racing,harvest] [--out /tmp/main-job]

Runs the README's main job in a fresh run directory (``--out`` is removed first) with the installed
``worldagent``, as a new user would (an empty compilation cache, no cached phase), and records its wall seconds,
the CPU seconds of its processes (user + sys: load-independent where wall is not), the load average
before it started, and each phase's own wall seconds and one-line result from the run's ``manifest.json``, with the machine,
in ``benchmarks/results/main-job-time-<backend>.json``, beside the run it replaces there (``previous``: its
commit, time and seconds, and the ratios) and every run recorded before that one (``history``, oldest first). ``--env racing,harvest`` is what a fresh install runs (``all`` also
takes installed example envs such as ``ued_maze``).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import RESULTS, children_cpu, record  # noqa: E402
from worldagent.reproduce.pipeline import CHAINS  # noqa: E402

TARGET_WALL_S = 600


def phase_seconds(manifest: dict) -> dict[str, float]:
    """Each phase's own wall seconds (``env/phase``), as the run recorded them."""
    return {name: phase["wall_s"] for name, phase in manifest["phases"].items() if phase.get("wall_s") is not None}


def phase_summaries(manifest: dict) -> dict[str, str]:
    """Each phase's one-line result (``env/phase``), as the run recorded it: what the timed budgets produced."""
    return {name: phase["outputs"]["summary"] for name, phase in manifest["phases"].items() if (phase.get("outputs") or {}).get("summary")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="racing,harvest", help="as reproduce's --env (default: what a fresh install has)")
    parser.add_argument("--out", type=Path, default=Path("/tmp/main-job"), help="run directory, removed first")
    parser.add_argument("--note", default="", help="what else was true of the run (recorded)")
    args = parser.parse_args()
    before = RESULTS / "main-job-time-cpu.json"
    previous = json.loads(before.read_text()) if before.exists() else None
    shutil.rmtree(args.out, ignore_errors=True)
    worldagent = Path(sys.executable).with_name("worldagent")
    command = [str(worldagent), "reproduce", "--preset", "quick", "--env", args.env, "--out", str(args.out)]
    load = os.getloadavg()[0]
    cpu, start = children_cpu(), time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="main-job-xla-") as cache:  # a first run's: empty (worldagent.compilation)
        done = subprocess.run(command, capture_output=True, text=True, env={**os.environ, "WORLDAGENT_COMPILATION_CACHE": cache})
    wall, cpu = time.perf_counter() - start, children_cpu() - cpu
    manifest = json.loads((args.out / "manifest.json").read_text())
    phases = phase_seconds(manifest)
    result = {
        "command": " ".join(["worldagent", *command[1:]]),
        "exit_code": done.returncode,
        "target_wall_s": TARGET_WALL_S,
        "wall_s": round(wall, 1),
        "cpu_s": round(cpu, 1),
        "load_before": round(load, 2),
        "phases": phases,
        "chains_s": chain_seconds(phases),
        "summaries": phase_summaries(manifest),
        "commit": commit(),
        **({"note": args.note} if args.note else {}),
    }
    if previous is not None:
        result["previous"] = summary(previous)
        result["ratio_to_previous"] = {key: round(result[key] / previous[key], 3) for key in ("wall_s", "cpu_s")}
        result["history"] = earlier_runs(previous)
    print(record("main-job-time", result))
    print(f"{wall:.0f} s wall ({wall / 60:.1f} min), {cpu:.0f} s CPU, exit {done.returncode}; target {TARGET_WALL_S} s")


def summary(run: dict) -> dict:
    """What a later record keeps of a run: when, which commit, its seconds and its note."""
    return {key: run.get(key) for key in ("when", "commit", "wall_s", "cpu_s", "note")}


def earlier_runs(previous: dict) -> list[dict]:
    """The runs recorded before ``previous``, oldest first: its own ``history`` and its ``previous``."""
    return [*previous.get("history", []), *([previous["previous"]] if previous.get("previous") else [])]


def commit() -> str:
    """The checkout's commit, with "+changes" when its tree differs from it."""
    here = Path(__file__).resolve().parent
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=here).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True, cwd=here).stdout.strip()
    return head + ("+changes" if dirty else "")


def chain_seconds(phases: dict[str, float]) -> dict[str, float]:
    """Each env's training chain and evaluation chain (``reproduce.pipeline.CHAINS``), summed."""
    training, _ = CHAINS
    chains: dict[str, float] = {}
    for name, seconds in phases.items():
        env, _, phase = name.partition("/")
        if phase:
            key = f"{env}/{'training' if phase in training else 'evaluation'}"
            chains[key] = round(chains.get(key, 0.0) + seconds, 1)
    return chains


if __name__ == "__main__":
    main()
