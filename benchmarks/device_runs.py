"""The training sections of ``device_check.py`` (issue 43): many runs as one program, and ``reproduce``.

    python benchmarks/device_runs.py ALGO MODE SEEDS EPISODES POOL OUT_DIR   # one many-runs measurement

Each many-runs measurement trains in a fresh process (compilation included, as a user pays it),
as ``many_runs.py`` does; ``part`` is ``device_sections.Part`` (the section's sizes, clock and results).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

ENVS = {"ppo": "racing", "acktr": "racing", "dqn": "harvest"}
OPTIONS = {"ppo": None, "acktr": {"observation": "rays"}, "dqn": None}  # ACKTR on rays: the paper's agent
QUICK_ALL_S = 300  # reproduce --preset quick end to end only with this much time left (8½ minutes on 2 CPU cores)


# -- many runs -----------------------------------------------------------------------------------


def measure(algo: str, mode: str, seeds: int, episodes: int, pool_size: int, out: Path) -> dict:
    """``many_runs.measure`` with the env's options (ACKTR on rays) and all seeds in one program."""
    import jax
    import numpy as np

    from many_runs import _cpu_seconds
    from worldagent.agents.algorithms import training_config
    from worldagent.agents.distributions import world_distribution
    from worldagent.agents.many import ManyRun, train_many
    from worldagent.agents.training import train

    env, options = ENVS[algo], OPTIONS[algo]
    pool = world_distribution(env, "generator", size=pool_size, seed=0)
    config = training_config(env, algo, episodes=episodes, options=options)
    cpu_before, start = _cpu_seconds(), time.perf_counter()
    if mode == "sequential":
        results = [train(env, algo, config, pool, out / f"seed{s}", seed=s, options=options, progress=False, resume=False) for s in range(seeds)]
    else:
        runs = [ManyRun(out / f"seed{s}", seed=s, distribution=pool) for s in range(seeds)]
        results = train_many(env, algo, config, runs, options=options, progress=False, resume=False, max_together=seeds)
    wall, cpu = time.perf_counter() - start, _cpu_seconds() - cpu_before
    # as many_runs.py: the first chunk of each program includes its compilation, the rest is the steady rate
    first, last = [float(r.curve["wall_seconds"][0]) for r in results], [float(r.curve["wall_seconds"][-1]) for r in results]
    steady = sum(b - a for a, b in zip(first, last)) if mode == "sequential" else max(last) - first[0]
    params = [np.asarray(x) for r in results for x in jax.tree_util.tree_leaves(r.agent.params)]
    np.savez(out / f"{mode}-params.npz", *params)
    return {
        "wall_s": round(wall, 2),
        "after_first_chunk_s": round(steady, 2),
        "cpu_s": round(cpu, 1),
        "episodes": [r.episodes for r in results],
        "env_steps": sum(r.env_steps for r in results),
    }


def run_measure(algo: str, mode: str, seeds: int, part, out: Path) -> dict:
    """One measurement in a fresh process, killed when the section's time is out."""
    sizes = part.sizes
    command = [sys.executable, __file__, algo, mode, str(seeds), str(sizes["episodes"][algo]), str(sizes["pool"]), str(out)]
    timeout = max(1.0, part.left())
    start = time.perf_counter()
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"cut_at_s": round(time.perf_counter() - start, 1), "note": "the section's time ran out during this measurement"}
    if done.returncode != 0:
        return {"failed": done.stderr.strip().splitlines()[-1:] or [f"exit {done.returncode}"]}
    return json.loads(done.stdout.strip().splitlines()[-1])


def compare(sequential: dict, together: dict) -> dict:
    """Speed-up of one program over one run after another (compilation included, and after each program's
    first chunk); a lower bound when the sequential runs were cut."""
    if "wall_s" in together and "wall_s" in sequential:
        found = {"speedup": round(sequential["wall_s"] / together["wall_s"], 2)}
        if together["after_first_chunk_s"] > 0:  # a budget of one chunk has no steady part
            found["speedup_after_first_chunk"] = round(sequential["after_first_chunk_s"] / together["after_first_chunk_s"], 2)
        return found
    if "wall_s" in together and "cut_at_s" in sequential:
        return {"speedup_at_least": round(sequential["cut_at_s"] / together["wall_s"], 2)}
    return {}


def keep_agent(algo: str, run_dir: Path, keep: Path) -> None:
    """Keep the first trained racing PPO for the decode section's evaluations (one training fewer)."""
    if algo == "ppo" and (run_dir / "policy").exists() and not keep.exists():
        shutil.copytree(run_dir, keep)


def many_runs(part) -> None:
    """PPO, ACKTR (rays) and DQN: N seeds as one vmapped program against one after another, N = 5, 1, 10."""
    from many_runs import max_difference

    sizes, rows = part.sizes, []
    part.put("episodes_per_run", sizes["episodes"])
    part.put("pool", f"procedural, {sizes['pool']} worlds")
    for seeds in sizes["seeds"]:
        for algo in sizes["algos"]:
            if part.left() < 5:
                rows.append({"algorithm": algo, "seeds": seeds, "skipped": "the section's time ran out"})
                part.put("runs", rows)
                continue
            with tempfile.TemporaryDirectory(dir=part.work) as tmp:
                row = {"algorithm": algo, "env": ENVS[algo], "options": OPTIONS[algo], "seeds": seeds}
                for mode in ("together", "sequential"):  # together first: a cut sequential still bounds the speed-up
                    row[mode] = run_measure(algo, mode, seeds, part, Path(tmp))
                row.update(compare(row["sequential"], row["together"]))
                if "wall_s" in row["sequential"] and "wall_s" in row["together"]:
                    row["max_param_difference"] = max_difference(Path(tmp))
                keep_agent(algo, Path(tmp) / "seed0", part.work / "ppo-agent")
            print(json.dumps(row), flush=True)
            rows.append(row)
            part.put("runs", rows)


# -- reproduce --preset quick --------------------------------------------------------------------


def quick(part) -> None:
    """``reproduce --preset quick`` end to end when the time left allows, else its slowest phase that stands
    alone: harvest's agent (DQN at the preset's budget, after its dataset). ``--smoke``: the tiny preset's
    racing dataset phase, to completion (all of ``reproduce`` would take minutes, and a cut run checks nothing)."""
    if part.smoke:
        slowest_phase(part, "racing", ("dataset",))
    elif part.left() >= QUICK_ALL_S:
        reproduce(part, "all")
    else:
        slowest_phase(part, "harvest", ("dataset", "agent"))


# reproduce's pipeline as ``worldagent reproduce --preset P --env E --out D --quiet`` runs it, without the CLI's typer
REPRODUCE = (
    "import sys; from pathlib import Path; from worldagent.reproduce.pipeline import reproduce, resolve_envs; "
    "from worldagent.reproduce.presets import get_preset; preset = get_preset(sys.argv[1]); "
    "reproduce(preset, Path(sys.argv[3]), resolve_envs(sys.argv[2], preset), progress=False)"
)


def reproduce(part, env: str) -> None:
    """``reproduce`` in a process of its own until done or out of time; phase wall times from its manifest."""
    out, preset = part.work / "reproduce", part.sizes["preset"]
    part.put("command", f"worldagent reproduce --preset {preset} --env {env} --quiet")
    start = time.perf_counter()
    try:
        done = subprocess.run([sys.executable, "-c", REPRODUCE, preset, env, str(out)], timeout=max(1.0, part.left()))
        part.put("exit", done.returncode)
        if done.returncode != 0:
            part.put("failed", f"reproduce exited with {done.returncode} (its traceback is in the log)")
    except subprocess.TimeoutExpired:
        part.put("exit", "cut: the section's time ran out")
    part.put("wall_s", round(time.perf_counter() - start, 1))
    part.put("phases", phase_times(out))


def slowest_phase(part, env: str, phases: tuple[str, ...]) -> None:
    """Run ``phases`` of one env of the preset through ``reproduce``'s phase functions, timing each."""
    from worldagent.reproduce.phases import PHASE_FUNCTIONS, EnvContext
    from worldagent.reproduce.presets import get_preset

    why = "smoke: tiny sizes" if part.smoke else "too little time for all"
    part.put("command", f"reproduce --preset {part.sizes['preset']}: {env}'s {' and '.join(phases)} phases only ({why})")
    ctx, times = EnvContext(part.work / "reproduce", env, get_preset(part.sizes["preset"]), progress=False), {}
    for phase in phases:
        times[f"{env}/{phase}"] = {"status": "running"}  # what a cut section's record shows
        part.put("phases", times)
        start = time.perf_counter()
        outputs = PHASE_FUNCTIONS[phase](ctx)
        times[f"{env}/{phase}"] = {"status": "done", "wall_s": round(time.perf_counter() - start, 2), "summary": outputs.get("summary")}
        part.put("phases", times)


def phase_times(run_dir: Path) -> dict:
    """{phase: {status, wall_s}} from a run directory's manifest (a running phase: its seconds so far)."""
    path = run_dir / "manifest.json"
    if not path.exists():
        return {}
    phases = json.loads(path.read_text()).get("phases", {})
    now = time.time()
    return {
        key: {"status": entry.get("status"), "wall_s": entry.get("wall_s", round(now - entry.get("started", now), 1))}
        for key, entry in phases.items()
    }


if __name__ == "__main__":
    algo, mode, seeds, episodes, pool, out = sys.argv[1:7]
    print(json.dumps(measure(algo, mode, int(seeds), int(episodes), int(pool), Path(out))))
