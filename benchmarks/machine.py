"""Describe the machine a benchmark ran on and record its result under benchmarks/results/."""

from __future__ import annotations

import json
import os
import platform
import resource
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
QUICK_RUN = "worldagent reproduce --preset quick"  # writes runs/quick: both envs' generator, agent and store


def require_input(path: Path | str, made_by: str) -> Path:
    """``path`` if it exists, else exit with one line naming the command that makes it.

    Benchmarks default their inputs to where a documented command writes them inside the checkout
    (``runs/quick/...``), never to a path of one machine; a fresh checkout has none of them yet.

    Args:
        path: an input file or directory an earlier run made.
        made_by: the command that makes it there.

    Returns:
        ``path`` as a ``Path``.
    """
    path = Path(path)
    if not path.exists():
        raise SystemExit(f"{path} does not exist: make it with `{made_by}`, or pass another")
    return path


def describe_machine() -> dict:
    """The facts that make a timing comparable: CPU, cores, memory, JAX backend and devices."""
    import jax

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        mem_gib = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError):
        mem_gib = float("nan")
    return {
        "cpu": cpu,
        "cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "memory_gib": round(mem_gib, 1),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "devices": [str(d.device_kind) for d in jax.devices()],
    }


def children_cpu() -> float:
    """CPU seconds (user + sys) of this process's finished children: load-independent where wall time is not."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def record(name: str, result: dict) -> Path:
    """Write ``result`` with the machine and a timestamp to ``results/<name>-<backend>.json``."""
    machine = describe_machine()
    payload = {"benchmark": name, "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "machine": machine, **result}
    from worldagent.files import write_text

    return write_text(RESULTS / f"{name}-{machine['backend']}.json", json.dumps(payload, indent=2) + "\n")
