"""jaxued's own maze PLR / ACCEL / DR examples, run as they ship, for issue 42 item 5.

    git clone https://github.com/DramaCow/jaxued JAXUED && git -C JAXUED checkout 0f8f128   # once, anywhere
    python benchmarks/ued_maze_jaxued.py --jaxued JAXUED --num-updates 150 --eval-freq 50 --seeds 0 1 2 3 4   # docs/ued-maze.md
    python benchmarks/ued_maze_jaxued.py --table   # the JSON's results as Markdown tables
    python benchmarks/ued_maze_jaxued.py --jaxued JAXUED --num-updates 150 --arms plr --seeds 0   # one arm, one seed
    python benchmarks/ued_maze_jaxued.py --jaxued JAXUED --num-updates 40 --eval-freq 20 --seeds 0 --work runs/ued-maze-jaxued-probe --out runs/ued-maze-jaxued-probe40.json  # throughput probe

The examples (``examples/maze_dr.py``, ``examples/maze_plr.py``) are not in jaxued's wheel, and
the wheel's library (0.0.1) still calls ``jax.tree_map``, gone from jax 0.10. So the run takes a
jaxued checkout (``--jaxued``, required to run: a clone, or a bare snapshot read with
``git archive``), copies its ``src/`` and the two example scripts into ``--work``, and
applies the small list of string patches in ``PATCHES`` (each says what and why) there; their
code is never committed here. The copy's ``src/`` comes first on ``PYTHONPATH``, so the examples
run against the library of the same commit.

Arms: ``dr`` (``maze_dr.py``), ``plr`` (``maze_plr.py``: robust PLR, MaxMC scores, rank
prioritisation, replay 0.8, buffer 4000) and ``accel`` (``maze_plr.py --use_accel``: 5 edits).
Every hyperparameter is the scripts' default (32 envs, 256 steps a rollout, lr 1e-4, an LSTM
student, 13x13 mazes of 25 walls, agent view 5, episodes of 250 steps) except the budget
(``--num_updates``, the same for every arm: one update is 32 x 256 env steps, whichever branch
PLR/ACCEL takes) and ``--checkpoint_save_interval 0`` (no orbax checkpoints). Their own eval is
the result: every ``--eval_freq`` updates, the policy plays each of the default ``--eval_levels``
prefabs ``--eval_num_attempts 10`` times; a level's solve rate is the share of attempts with a
positive return. We keep the last eval (per level and the mean) and the curve of means.

One run at a time, seed-major (dr, plr, accel for seed 0, then seed 1, ...), so a partial
benchmark stays balanced. Resumable: a run already in ``--out`` at the same budget is skipped.
Writes ``benchmarks/results/ued-maze-jaxued.json``: the machine, the jaxued commit, the patches,
the settings the runs logged, the budget, per-run values and per-arm mean +- 95% t-intervals.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import os
import shutil
import subprocess
import sys
import tarfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import RESULTS, describe_machine  # noqa: E402

SCRIPTS = {"dr": "maze_dr.py", "plr": "maze_plr.py", "accel": "maze_plr.py"}
ARM_FLAGS = {"dr": [], "plr": [], "accel": ["--use_accel"]}

# Replaces ``wandb`` (not installed here, and we log nowhere remote): ``init`` keeps the config
# the script passes, ``log`` appends the numeric entries of each eval's dict to $JAXUED_LOG as a
# JSON line (arrays as their mean); images and videos are dropped.
WANDB_SHIM = '''"""Local stand-in for wandb: one JSON line per wandb.log call, numbers only."""
import json
import os
import time

import numpy as np

config = None


class _Config(dict):
    def __getattr__(self, key):
        try:
            return self[key]
        except KeyError as err:
            raise AttributeError(key) from err

    def as_dict(self):
        return dict(self)


def _write(record):
    with open(os.environ["JAXUED_LOG"], "a") as f:
        f.write(json.dumps(record) + "\\n")


def init(config=None, **kwargs):
    globals()["config"] = _Config(config or {})
    _write({"config": dict(config or {}), "init": {k: v for k, v in kwargs.items()}, "time": time.time()})


def define_metric(*args, **kwargs):
    pass


def log(log_dict):
    record = {}
    for key, value in log_dict.items():
        try:
            arr = np.asarray(value)
        except Exception:
            continue
        if arr.dtype.kind in "biuf" and arr.size:
            # Arrays (maze_dr.py's per-update losses over a chunk) are kept as their mean.
            record[key] = arr.item() if arr.size == 1 else float(arr.mean())
    record["time"] = time.time()
    _write(record)


def Image(*args, **kwargs):
    return None


def Video(*args, **kwargs):
    return None
'''

# (file, old, new, count, why). Applied in order to the copies in --work; each ``old`` must
# occur exactly ``count`` times, so an upstream change fails loudly instead of running unpatched.
PATCHES: list[tuple[str, str, str, int, str]] = [
    (
        "maze_plr.py",
        "import wandb\n",
        "import wandb_shim as wandb\n",
        1,
        "remove wandb: the local shim (wandb_shim.py, written by this benchmark) logs each eval's numbers to a JSON-lines file",
    ),
    (
        "maze_dr.py",
        "import wandb\n",
        "import wandb_shim as wandb\n",
        1,
        "remove wandb: the local shim (wandb_shim.py, written by this benchmark) logs each eval's numbers to a JSON-lines file",
    ),
]


# What else differs from running the scripts as their README says, none of it a code change.
SETUP = [
    "library: the checkout's own src/jaxued first on PYTHONPATH, not the jaxued 0.0.1 wheel, whose "
    "jax.tree_map calls fail on jax 0.10 (AttributeError); upstream commit 0f8f128 moved them to "
    "jax.tree_util.tree_map, so at that commit or later no jax-0.10 code patch is needed",
    "command line: --checkpoint_save_interval 0 (their own switch: no orbax checkpoints), --num_updates and "
    "--eval_freq (the budget), --seed, --eval_num_attempts 10 (their default, passed explicitly)",
    "environment: JAX_COMPILATION_CACHE_DIR (XLA's persistent cache; same programs, compiled once per arm)",
]


def t_quantile_975(df: int) -> float:
    from scipy.stats import t

    return float(t.ppf(0.975, df))


def summarise(values: list[float]) -> dict:
    """Mean and 95% Student-t interval over seeds (None where fewer than two)."""
    n = len(values)
    mean = sum(values) / n if n else float("nan")
    out = {"n": n, "mean": mean, "values": values}
    if n >= 2:
        sd = math.sqrt(sum((v - mean) ** 2 for v in values) / (n - 1))
        half = t_quantile_975(n - 1) * sd / math.sqrt(n)
        out.update({"sd": sd, "ci95": [mean - half, mean + half], "ci95_half_width": half})
    return out


def checkout(source: str, dest: Path) -> dict:
    """Copy the checkout's src/ and the two example scripts into dest; return where and which commit."""
    src = Path(source).expanduser()
    paths = ["src/jaxued", *[f"examples/{name}" for name in sorted(set(SCRIPTS.values()))]]
    if dest.exists():
        shutil.rmtree(dest)
    dest.mkdir(parents=True)
    commit = subprocess.run(["git", "-C", str(src), "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    is_bare = subprocess.run(["git", "-C", str(src), "rev-parse", "--is-bare-repository"], capture_output=True, text=True).stdout.strip() == "true"
    if is_bare or not (src / "src" / "jaxued").is_dir():
        # A snapshot without a work tree (the stored mirror): read the files at HEAD.
        archive = subprocess.run(["git", "-C", str(src), "archive", "HEAD", *paths], capture_output=True, check=True)
        with tarfile.open(fileobj=io.BytesIO(archive.stdout)) as tar:
            tar.extractall(dest, filter="data")
    else:
        for p in paths:
            (shutil.copytree if (src / p).is_dir() else shutil.copy2)(src / p, dest / p)
    for name in sorted(set(SCRIPTS.values())):
        shutil.move(dest / "examples" / name, dest / name)
    (dest / "wandb_shim.py").write_text(WANDB_SHIM)
    for file, old, new, count, why in PATCHES:
        path = dest / file
        text = path.read_text()
        found = text.count(old)
        if found != count:
            raise SystemExit(f"patch for {file} ({why}): expected {count} occurrence(s), found {found}")
        path.write_text(text.replace(old, new))
    return {"source": str(src), "commit": commit}


def env_defaults(work: Path) -> dict:
    """The maze's episode length and view as the checkout's library defines them (not hard-coded here)."""
    code = (
        "import json; from jaxued.environments import Maze\n"
        "env = Maze(max_height=13, max_width=13)\n"
        "print(json.dumps({'max_steps_in_episode': int(env.default_params.max_steps_in_episode),"
        " 'agent_view_size': env.agent_view_size, 'max_height': env.max_height, 'max_width': env.max_width,"
        " 'num_actions': int(env.action_space(env.default_params).n)}))"
    )
    out = subprocess.run([sys.executable, "-c", code], env=run_env(work, None), capture_output=True, text=True)
    if out.returncode:
        raise SystemExit(out.stderr)
    return json.loads(out.stdout.strip().splitlines()[-1])


def run_env(work: Path, log: Path | None) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(work / "src"), str(work), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    # JAX's persistent cache, so later seeds of an arm reuse the first one's compiled programs
    # (about a minute of XLA compilation per run on these cores); it changes no computation.
    env.setdefault("JAX_COMPILATION_CACHE_DIR", str(work.parent / "jax-cache"))
    if log is not None:
        env["JAXUED_LOG"] = str(log)
    return env


def one_run(work: Path, arm: str, seed: int, args: argparse.Namespace) -> dict:
    log = work.parent / "logs" / f"{arm}-seed{seed}.jsonl"  # outside the copy, which each start rebuilds
    log.parent.mkdir(exist_ok=True)
    log.unlink(missing_ok=True)
    cmd = [
        sys.executable,
        SCRIPTS[arm],
        "--seed",
        str(seed),
        "--num_updates",
        str(args.num_updates),
        "--eval_freq",
        str(args.eval_freq),
        "--eval_num_attempts",
        str(args.eval_num_attempts),
        "--checkpoint_save_interval",
        "0",
        *ARM_FLAGS[arm],
    ]
    print(f"[{time.strftime('%H:%M:%S')}] {arm} seed {seed}: {' '.join(cmd[1:])}", flush=True)
    start = time.time()
    proc = subprocess.run(cmd, cwd=work, env=run_env(work, log))
    wall = time.time() - start
    if proc.returncode:
        raise SystemExit(f"{arm} seed {seed} failed ({proc.returncode}); its log: {log}")
    records = [json.loads(line) for line in log.read_text().splitlines()]
    config = records[0]["config"]
    evals = [r for r in records[1:] if "num_env_steps" in r]
    last = evals[-1]
    levels = config["eval_levels"]
    per_level = {name: last[f"solve_rate/{name}"] for name in levels}
    # Their log_eval times each train+eval chunk; the first includes compilation.
    chunk_s = [r["time"] - prev["time"] for prev, r in zip(records, records[1:])]
    result = {
        "arm": arm,
        "seed": seed,
        "num_updates": last["num_updates"],
        "env_steps": last["num_env_steps"],
        "wall_s": wall,
        "train_eval_s_after_first_chunk": sum(chunk_s[1:]),
        "env_steps_per_s_after_first_chunk": ((last["num_env_steps"] - evals[0]["num_env_steps"]) / sum(chunk_s[1:]) if len(evals) > 1 else None),
        "solve_rates": per_level,
        "mean_solve_rate": sum(per_level.values()) / len(per_level),
        "mean_return": last["return/mean"],
        # Wall seconds between their eval logs: their own "sps" times only the jitted call's
        # dispatch (JAX runs it asynchronously), so it is not a throughput.
        "curve": [{"num_env_steps": r["num_env_steps"], "solve_rate_mean": r["solve_rate/mean"], "chunk_s": dt} for r, dt in zip(evals, chunk_s)],
        "command": " ".join(cmd[1:]),
        "config": config,
    }
    print(
        f"  {arm} seed {seed}: {result['env_steps']} env steps in {wall:.0f} s, mean solve {result['mean_solve_rate']:.3f}",
        flush=True,
    )
    return result


def markdown_table(result: dict) -> str:
    """Per-seed and mean +- 95% t-interval held-out solve rates per arm, and each run's wall time."""

    def ci(summary: dict) -> str:
        if "ci95_half_width" not in summary:
            return f"{summary['mean']:.3f}"
        return f"{summary['mean']:.3f} ± {summary['ci95_half_width']:.3f}"

    runs = result["runs"]
    seeds = sorted({r["seed"] for r in runs})
    lines = [
        "| arm | " + " | ".join(f"seed {s}" for s in seeds) + " | mean ± 95% t | wall s per run |",
        "|---|" + "---|" * len(seeds) + "---|---|",
    ]
    for arm, summary in result["arms"].items():
        by_seed = {r["seed"]: r for r in runs if r["arm"] == arm}
        cells = [f"{by_seed[s]['mean_solve_rate']:.3f}" if s in by_seed else "–" for s in seeds]
        walls = " / ".join(f"{by_seed[s]['wall_s']:.0f}" for s in seeds if s in by_seed)
        lines.append(f"| {arm} | " + " | ".join(cells) + f" | {ci(summary['mean_solve_rate'])} | {walls} |")
    levels = result["training_settings"]["eval_levels"]
    lines += ["", "| arm | " + " | ".join(levels) + " |", "|---|" + "---|" * len(levels)]
    for arm, summary in result["arms"].items():
        lines.append(f"| {arm} | " + " | ".join(ci(summary["solve_rates"][name]) for name in levels) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--jaxued", help="a jaxued git checkout or snapshot (git clone https://github.com/DramaCow/jaxued, commit 0f8f128)")
    parser.add_argument("--arms", nargs="+", default=["dr", "plr", "accel"], choices=list(SCRIPTS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--num-updates", type=int, help="their --num_updates, every arm (required to run)")
    parser.add_argument("--eval-freq", type=int, default=None, help="their --eval_freq (default: num-updates)")
    parser.add_argument("--eval-num-attempts", type=int, default=10)
    parser.add_argument("--work", default="runs/ued-maze-jaxued", help="the patched copy and the runs' logs")
    parser.add_argument("--out", default=str(RESULTS / "ued-maze-jaxued.json"))
    parser.add_argument("--throughput-probe", help="an earlier short run's JSON, kept in --out as the throughput probe")
    parser.add_argument("--table", action="store_true", help="print --out's results as Markdown tables and exit")
    args = parser.parse_args()
    if args.table:
        print(markdown_table(json.loads(Path(args.out).read_text())))
        return
    if args.num_updates is None:
        parser.error("--num-updates is required to run")
    if args.jaxued is None:
        parser.error("--jaxued is required to run: a jaxued checkout (git clone https://github.com/DramaCow/jaxued; commit 0f8f128)")
    args.eval_freq = args.eval_freq or args.num_updates
    if args.num_updates % args.eval_freq:
        # Their loop runs num_updates // eval_freq chunks: a remainder would silently not train.
        raise SystemExit("--num-updates must be a multiple of --eval-freq")

    work = Path(args.work).resolve()
    source = checkout(args.jaxued, work / "jaxued")
    defaults = env_defaults(work / "jaxued")
    out = Path(args.out)
    payload = json.loads(out.read_text()) if out.exists() else {}
    done = {
        (r["arm"], r["seed"]): r
        for r in payload.get("runs", [])
        if r["num_updates"] == args.num_updates and r["config"]["eval_num_attempts"] == args.eval_num_attempts
    }
    runs = list(done.values())
    probe = None
    if args.throughput_probe:
        # The short runs the budget was chosen from: per arm, wall seconds per chunk of updates.
        probe_runs = json.loads(Path(args.throughput_probe).read_text())["runs"]
        probe = [{k: r[k] for k in ("arm", "seed", "num_updates", "env_steps", "wall_s", "curve", "command")} for r in probe_runs]

    def write() -> None:
        by_arm = {}
        for arm in args.arms:
            rs = sorted((r for r in runs if r["arm"] == arm), key=lambda r: r["seed"])
            if rs:
                by_arm[arm] = {
                    "seeds": [r["seed"] for r in rs],
                    "mean_solve_rate": summarise([r["mean_solve_rate"] for r in rs]),
                    "solve_rates": {name: summarise([r["solve_rates"][name] for r in rs]) for name in rs[0]["solve_rates"]},
                    "wall_s": summarise([r["wall_s"] for r in rs]),
                }
        config = runs[0]["config"] if runs else {}
        steps = sorted({r["env_steps"] for r in runs}) or [None]
        keys = ["num_train_envs", "num_steps", "lr", "epoch_ppo", "num_minibatches", "gamma", "gae_lambda"]
        keys += ["clip_eps", "entropy_coeff", "critic_coeff", "max_grad_norm", "n_walls", "agent_view_size"]
        keys += ["eval_levels", "eval_num_attempts", "eval_freq"]
        plr_keys = ["score_function", "replay_prob", "level_buffer_capacity", "staleness_coeff", "temperature"]
        plr_keys += ["prioritization", "minimum_fill_ratio", "exploratory_grad_updates", "buffer_duplicate_check"]
        plr_keys += ["num_edits"]
        plr_config = next((r["config"] for r in runs if r["arm"] != "dr"), {})
        result = {
            "benchmark": "ued-maze-jaxued",
            "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "machine": describe_machine(),
            "niceness": os.nice(0),
            "load_note": "one run at a time, on cores shared with other jobs: timings are under load",
            "throughput_probe": probe,
            "jaxued": source,
            "patches": [{"file": f, "old": o, "new": n, "why": w} for f, o, n, _, w in PATCHES],
            "setup": SETUP,
            "budget": {
                "num_updates": args.num_updates,
                "env_steps_per_update": (config["num_train_envs"] * config["num_steps"]) if config else None,
                "env_steps_per_run": (config["num_train_envs"] * config["num_steps"] * args.num_updates) if config else None,
                "eval_freq": args.eval_freq,
            },
            # What the runs logged (their num_env_steps at the last eval): the other side's budget.
            "env_steps_per_run": steps[0] if len(steps) == 1 else steps,
            "training_settings": {k: config.get(k) for k in keys} | defaults,
            "plr_accel_settings": {k: plr_config.get(k) for k in plr_keys},
            "arms": by_arm,
            "runs": sorted(runs, key=lambda r: (r["seed"], args.arms.index(r["arm"]) if r["arm"] in args.arms else 9)),
        }
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(result, indent=2) + "\n")

    for seed in args.seeds:
        for arm in args.arms:
            if (arm, seed) in done:
                print(f"{arm} seed {seed}: already in {out}, skipped", flush=True)
                continue
            runs.append(one_run(work / "jaxued", arm, seed, args))
            write()
    write()
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
