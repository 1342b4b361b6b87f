"""Every GPU figure of worldagent from one command of at most 8 minutes (issue 43).

On a machine with an NVIDIA GPU, from the repository root, with ``.whl/`` made here beforehand by
``bash benchmarks/device_wheels.sh`` (the Python 3.12 wheels the machine lacks; docs/gpu.md)::

    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \\
      && export PYTHONPATH=/tmp/site:src PYTHONUNBUFFERED=1 || exit; python3 benchmarks/device_check.py --out "$OUT"

On CPU, in CI (tiny sizes, every section run to completion: under 2.5 minutes on 2 quiet cores, longer
on busy ones, never failing for that; the values are CPU values and say so)::

    python benchmarks/device_check.py --smoke --out /tmp/device-smoke

It writes ``<out>/device-<card>.json`` (``--smoke``: ``device-<card>-smoke.json``; card: ``h100``,
``h200``, ``cpu``) and the log beside it (``.log``): the card, its driver and CUDA version, JAX's
versions, the commit, and five sections, each run in a process of its own (``device_sections.py``)
and, on the GPU, killed at its own time cap, so a section cut short still reports what it measured,
and a spent budget skips the rest with a note (``--smoke`` has no caps: a section past ``HUNG_S`` hung):

- ``machine``: JAX's backend, device kind, memory limit and CUDA plugin;
- ``env_throughput``: racing steps/s and harvest agent-steps/s at 4,096, 65,536 and the largest
  batch that fits (XLA's memory plan scaled from 65,536, halved while it runs out);
- ``many_runs``: PPO (racing), ACKTR (racing, rays) and DQN (harvest) at 10x many-runs.json's budgets,
  5, 1 and 10 seeds as one program against one after another (each a fresh process, compilation
  included), 5 first; a sequential run cut by the cap gives a lower bound of the speed-up;
- ``decode_search``: racing's G(z) at 32, 1,024 and 16,384 latents with both repairs (``nearest``
  over 10,000 tracks, ``open``), one CMA-ES generation and 1,000 worlds x 8 with a trained PPO;
- ``quick``: ``reproduce --preset quick`` end to end with the time left, phase wall times from its
  manifest; with under 5 minutes left, its slowest phase that runs alone (harvest's DQN agent);
  ``--smoke``: the tiny preset's racing dataset phase.

``--sections`` runs some sections only, ``--set NAME=JSON`` changes a size of
``device_sections.SIZES`` (a rerun in what is left of a lease). The parent process never imports
JAX: on a GPU each process takes most of the card's memory. Exit status 1 if a section or a
measurement failed, or under ``--smoke`` if a section hung or recorded nothing of what it must (``RECORDS``).
"""

from __future__ import annotations

import argparse
import collections
import json
import math
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SIZES_VARIABLE = "WORLDAGENT_DEVICE_SIZES"  # device_sections.SIZES_VARIABLE (not imported: it would import JAX's users)
SECTIONS = ("machine", "env_throughput", "many_runs", "decode_search", "quick")
CAPS = {  # seconds per section; None: whatever is left
    "full": {"machine": 30, "env_throughput": 60, "many_runs": 260, "decode_search": 80, "quick": None},
}
# --smoke (CI) runs every section to completion at its tiny sizes, so a slow or busy machine makes it
# slower, never failing (at a load average of 5 the old 10-24 s caps ran out during compilations);
# a section still running after this long has hung, and that is a failure
HUNG_S = 600
BUDGET = {"full": 470, "smoke": None}  # seconds in all (GPU: the 8 minutes, less the start); None: no limit
SHORTEST = {"full": 20, "smoke": 3}  # a section given less than this is skipped with a note
RECORDS = {  # what each section must record under --smoke (CI): a section that loses one fails the check
    "machine": ("jax",),
    "env_throughput": ("racing", "harvest"),
    "many_runs": ("runs",),
    "decode_search": ("decode", "cmaes_generation_s", "random_evaluation"),
    "quick": ("phases",),
}


def shell(command: list[str], cwd: Path = ROOT) -> str | None:
    """A command's stdout, or None when it is missing or fails."""
    try:
        return subprocess.run(command, cwd=cwd, capture_output=True, text=True, timeout=30, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None


def card() -> dict:
    """The GPU as nvidia-smi names it (card: a short name for file names), or the CPU."""
    listing = shell(["nvidia-smi", "--query-gpu=name,driver_version,memory.total", "--format=csv,noheader"])
    if not listing:
        return {"card": "cpu", "gpu": None, "driver": None, "cuda": None}
    name, driver, memory = [x.strip() for x in listing.splitlines()[0].split(",")][:3]
    cuda = re.search(r"CUDA Version:\s*([\d.]+)", shell(["nvidia-smi"]) or "")
    short = re.search(r"\b([A-Z]\d{2,4})\b", name)
    slug = short.group(1).lower() if short else re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-")
    return {"card": slug, "gpu": name, "gpus": len(listing.splitlines()), "driver": driver, "cuda": cuda and cuda.group(1), "memory": memory}


def commit() -> dict:
    """The commit measured: git's, else the one ``device_wheels.sh`` wrote beside the wheels (the
    device machine gets the working tree without .git)."""
    head = shell(["git", "rev-parse", "HEAD"])
    if head:
        return {"commit": head, "dirty": bool(shell(["git", "status", "--porcelain", "--untracked-files=no"]))}
    noted = ROOT / ".whl" / "COMMIT"
    return json.loads(noted.read_text()) if noted.exists() else {"commit": None}


def copy_lines(stream, prefix: str, log, tail: collections.deque) -> None:
    """Echo a child's output to our stdout and the log, keeping its last lines for an error message."""
    for line in stream:
        tail.append(line.rstrip())
        text = f"[{prefix}] {line}"
        sys.stdout.write(text)
        sys.stdout.flush()
        log.write(text)
        log.flush()


def section_cap(mode: str, name: str, left: float) -> float:
    """Seconds section ``name`` may run: its cap within the ``left`` of the budget; under ``--smoke``, until done
    (at most ``HUNG_S``, and within an explicit ``--budget``)."""
    if mode == "smoke":
        return min(HUNG_S, left)
    return min(CAPS[mode][name] or left, left)


def run_section(name: str, cap: float, work: Path, smoke: bool, log, sizes: dict) -> dict:
    """Run one section in a child process, killed (with all it started) at ``cap`` seconds; under ``smoke``
    a section cut at its cap has hung (smoke sections run to completion), and is ``failed``."""
    part = work / f"{name}.json"
    command = [sys.executable, str(HERE / "device_sections.py"), name, "--work", str(work), "--part", str(part), "--cap", f"{cap:.0f}"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1", SIZES_VARIABLE: json.dumps(sizes)}
    start, tail = time.perf_counter(), collections.deque(maxlen=6)
    child = subprocess.Popen(
        [*command, *(["--smoke"] if smoke else [])], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, start_new_session=True
    )
    reader = threading.Thread(target=copy_lines, args=(child.stdout, name, log, tail), daemon=True)
    reader.start()
    try:
        code = child.wait(timeout=cap + 2)  # the child stops its own subprocesses 2 s before its cap
        status = "done" if code == 0 else "failed"
    except subprocess.TimeoutExpired:
        os.killpg(child.pid, signal.SIGKILL)  # its own session: the section and every process it started
        child.wait()
        status = "failed" if smoke else "cut at its cap"
        tail.append(f"cut at {cap:.0f} s: a smoke section runs to completion, so it hung (or the --budget was too small)")
    reader.join(timeout=5)
    found = json.loads(part.read_text()) if part.exists() else {}
    entry = {"status": status, "wall_s": round(time.perf_counter() - start, 1), "cap_s": round(cap), **found}
    if status == "failed":
        entry["error"] = list(tail)
    return entry


def header(args, gpu: dict) -> dict:
    """The JSON's opening fields: what ran, where, at which commit."""
    values = "GPU" if gpu["gpu"] else "CPU values (no GPU found): not GPU figures"
    return {
        "benchmark": "device-check",
        "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "values": values + (" (--smoke: tiny sizes, the numbers mean nothing)" if args.smoke else ""),
        **gpu,
        **commit(),
        "command": "python benchmarks/device_check.py " + " ".join(sys.argv[1:]),
        "budget_s": args.budget,
        "sizes_set": args.set,
        "sections": {},
    }


def headline(result: dict) -> dict:
    """The figures the issue asks first: 5 seeds as one program against one after another, per algorithm."""
    runs = result["sections"].get("many_runs", {}).get("runs", [])
    five = {r["algorithm"]: r.get("speedup", r.get("speedup_at_least")) for r in runs if r.get("seeds") == 5}
    jax_info = result["sections"].get("machine", {}).get("jax", {})
    return {"jax": jax_info.get("jax"), "jaxlib": jax_info.get("jaxlib"), "backend": jax_info.get("backend"), "five_seeds_speedup": five}


def missing_records(result: dict) -> list[str]:
    """``section.key`` for every record a section should have made and did not."""
    return [f"{name}.{key}" for name, keys in RECORDS.items() for key in keys if key not in result["sections"].get(name, {})]


def failures(found, where: str = "") -> list[str]:
    """Where in the results a measurement failed (a ``failed`` key): a section may go on past one."""
    if isinstance(found, dict):
        own = [where or "."] if "failed" in found else []
        return own + [path for key, value in found.items() for path in failures(value, f"{where}.{key}" if where else key)]
    if isinstance(found, list):
        return [path for i, value in enumerate(found) for path in failures(value, f"{where}[{i}]")]
    return []


def write(path: Path, result: dict) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(result, indent=2) + "\n")
    tmp.replace(path)


def run_all(args, result: dict, path: Path, log) -> None:
    """Each section in order within its cap and the budget left; the JSON rewritten after each."""
    mode, started = ("smoke" if args.smoke else "full"), time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="device-check-") as work:
        for name in SECTIONS:
            left = (args.budget if args.budget is not None else math.inf) - (time.perf_counter() - started) - 2
            cap = section_cap(mode, name, left)
            if name not in args.sections:
                result["sections"][name] = {"skipped": "not asked for (--sections)"}
            elif cap < SHORTEST[mode]:
                result["sections"][name] = {"skipped": f"the budget ran out: {max(left, 0):.0f} s left of {args.budget:.0f} s"}
            else:
                print(f"== {name} ({'to completion, hung after' if args.smoke else 'at most'} {cap:.0f} s)", flush=True)
                result["sections"][name] = run_section(name, cap, Path(work), args.smoke, log, args.set)
            result["headline"] = headline(result)
            result["wall_s"] = round(time.perf_counter() - started, 1)
            write(path, result)


def sizes_set(text: str) -> tuple[str, object]:
    """``NAME=JSON`` of ``--set`` as (name, value)."""
    name, sep, value = text.partition("=")
    try:
        return name.strip(), json.loads(value)
    except ValueError:
        raise SystemExit(f"--set {text!r}: write NAME=JSON, e.g. seeds=[5] or 'algos=[\"ppo\"]'.") from None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true", help="tiny sizes, each section to completion: under 2.5 minutes on 2 quiet CPU cores (CI)")
    parser.add_argument("--out", type=Path, default=HERE / "results", help="folder of the JSON and the log (default benchmarks/results)")
    parser.add_argument("--budget", type=float, default=None, help="seconds in all (default 470; --smoke: no limit)")
    parser.add_argument("--sections", nargs="+", choices=SECTIONS, default=list(SECTIONS), help="run only these (the others are recorded as skipped)")
    parser.add_argument(
        "--set", nargs="+", default=[], metavar="NAME=JSON", help="change a size of device_sections.SIZES, e.g. seeds=[5] 'algos=[\"ppo\"]'"
    )
    args = parser.parse_args(argv)
    args.set = dict(sizes_set(text) for text in args.set)
    args.budget = args.budget if args.budget is not None else BUDGET["smoke" if args.smoke else "full"]
    gpu = card()
    args.out.mkdir(parents=True, exist_ok=True)
    stem = f"device-{gpu['card']}" + ("-smoke" if args.smoke else "")
    path, result = args.out / f"{stem}.json", header(args, gpu)
    with open(args.out / f"{stem}.log", "w") as log:
        run_all(args, result, path, log)
    failed = [name for name, entry in result["sections"].items() if entry.get("status") == "failed"] + failures(result["sections"])
    missing = missing_records(result) if args.smoke else []
    print(f"recorded in {path} ({result['wall_s']} s): {json.dumps(result['headline'])}")
    if failed or missing:
        print(f"failed: {failed or 'none'}; missing records: {missing or 'none'}", file=sys.stderr)
    return 1 if failed or missing else 0


if __name__ == "__main__":
    sys.exit(main())
