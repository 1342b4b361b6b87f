"""The default test suite's time (the README's `pytest`), this commit beside the previous main, one after the other.

    python benchmarks/test_suite_time.py --commits HEAD PREVIOUS_MAIN [--runs 1]

Each commit is cloned from this repository into a temporary folder and its suite run there with this
virtualenv's Python, the clone's ``src`` first on the path (the editable install is not what is timed).
Recorded per commit and run: wall seconds, the CPU seconds of the run's processes (user + sys of the
children: load-independent where wall is not), the passed/skipped counts and the load average before
it started, in ``benchmarks/results/test-suite-time-<backend>.json`` with the machine and the wall and CPU ratios
of the first commit to the second. The target is 300 s of wall on 2 cores (issue 49).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import children_cpu, record  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SUMMARY = re.compile(r"(\d+) passed(?:, (\d+) skipped)?")


def time_suite(commit: str, workdir: Path) -> dict:
    """One run of ``pytest`` (the README's command) on a clone of ``commit``."""
    clone = workdir / commit.replace("/", "_")
    if not clone.exists():
        subprocess.run(["git", "clone", "-q", str(REPO), str(clone)], check=True)
        subprocess.run(["git", "-C", str(clone), "checkout", "-q", commit], check=True)
    sha = subprocess.run(["git", "-C", str(clone), "rev-parse", "--short", "HEAD"], check=True, capture_output=True, text=True).stdout.strip()
    env = {**os.environ, "PYTHONPATH": str(clone / "src")}
    load = os.getloadavg()[0]
    cpu, start = children_cpu(), time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "pytest"], cwd=clone, env=env, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - start, children_cpu() - cpu
    counts = SUMMARY.search(done.stdout.splitlines()[-1] if done.stdout else "")
    return {
        "commit": sha,
        "exit_code": done.returncode,
        "wall_s": round(wall, 1),
        "cpu_s": round(cpu, 1),
        "passed": int(counts.group(1)) if counts else None,
        "skipped": int(counts.group(2) or 0) if counts else None,
        "load_before": round(load, 2),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--commits", nargs=2, default=["HEAD", "HEAD~1"], metavar=("NEW", "PREVIOUS"))
    parser.add_argument("--runs", type=int, default=1, help="runs of each commit, alternating")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="suite-time-") as folder:
        commits = [
            subprocess.run(["git", "-C", str(REPO), "rev-parse", c], check=True, capture_output=True, text=True).stdout.strip() for c in args.commits
        ]
        runs = [time_suite(commit, Path(folder)) for _ in range(args.runs) for commit in commits]
    new, old = ([r for r in runs if commit.startswith(r["commit"])] for commit in commits)
    best = lambda rows, key: min(r[key] for r in rows)  # noqa: E731  (the least-disturbed run)
    result = {
        "command": "pytest (the README's test command)",
        "target_wall_s": 300,
        "runs": runs,
        "wall_ratio_new_to_previous": round(best(new, "wall_s") / best(old, "wall_s"), 3),
        "cpu_ratio_new_to_previous": round(best(new, "cpu_s") / best(old, "cpu_s"), 3),
    }
    print(record("test-suite-time", result))
    for row in runs:
        print(f"{row['commit']}: {row['wall_s']:.0f} s wall, {row['cpu_s']:.0f} s CPU, {row['passed']} passed (load {row['load_before']})")


if __name__ == "__main__":
    main()
