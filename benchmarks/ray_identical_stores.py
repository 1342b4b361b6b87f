"""Ray and local campaigns fill identical stores, on a busy machine, with a jitted and an ONNX agent (issue 30).

    python benchmarks/ray_identical_stores.py --run runs/quick [--attempts 5] [--budget 210] [--busy 1]

For each agent (the scripted racing ``driver``, and the run's trained PPO actor exported to
ONNX, an external agent played by the host evaluator), ``worldagent search racing --minimize``
runs once with ``--backend local`` and ``--attempts`` times with ``--backend ray`` (a local
cluster of 2 workers, so each generation of 21 worlds is split 11 + 10), while ``--busy``
processes spin on the CPU. Every Ray store is compared with the local one evaluation by
evaluation: latent, score and every episode's metrics. The commands run as a user runs them, in
fresh processes with JAX's default compiler settings. Writes
``benchmarks/results/ray-identical-stores-cpu.json`` with the machine.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import QUICK_RUN, record, require_input  # noqa: E402

CAMPAIGN = "cmaes-min-return-s0"


def actor_onnx(agent_dir: Path, path: Path) -> Path:
    """The saved PPO agent's actor (dense-tanh-dense-tanh-dense logits) as an ONNX model."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    from worldagent.agents.loaders import load_agent

    actor = load_agent("racing", str(agent_dir)).params["params"]["actor"]
    layers = [(np.asarray(actor[f"Dense_{i}"]["kernel"]), np.asarray(actor[f"Dense_{i}"]["bias"])) for i in range(3)]
    nodes, weights, current = [], [], "obs"
    for i, (kernel, bias) in enumerate(layers):
        weights += [numpy_helper.from_array(kernel, f"W{i}"), numpy_helper.from_array(bias, f"b{i}")]
        nodes += [helper.make_node("MatMul", [current, f"W{i}"], [f"m{i}"]), helper.make_node("Add", [f"m{i}", f"b{i}"], [f"a{i}"])]
        current = f"a{i}"
        if i < len(layers) - 1:
            nodes.append(helper.make_node("Tanh", [current], [f"h{i}"]))
            current = f"h{i}"
    nodes.append(helper.make_node("Identity", [current], ["logits"]))
    graph = helper.make_graph(
        nodes,
        "ppo_actor",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, [None, layers[0][0].shape[0]])],
        [helper.make_tensor_value_info("logits", TensorProto.FLOAT, [None, layers[-1][0].shape[1]])],
        weights,
    )
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]), str(path))
    return path


def evaluations(store_dir: Path) -> list[tuple]:
    """The campaign's evaluations as comparable rows, in (generation, slot) order."""
    from worldagent.store import RunStore

    with RunStore(store_dir) as store:
        rows = store.iter_evaluations(CAMPAIGN)
        return sorted((e.generation, e.slot, e.latent.tolist(), e.score, json.dumps(e.episodes, sort_keys=True)) for e in rows)


def search(agent: str, generator: Path, out: Path, backend: str, budget: int) -> float:
    """Seconds ``worldagent search`` took on ``backend``."""
    command = ["worldagent", "search", "racing", "--agent", agent, "--generator", str(generator), "--minimize"]
    command += ["--budget", str(budget), "--backend", backend, "--out", str(out), "--quiet"]
    env = {key: value for key, value in os.environ.items() if key != "XLA_FLAGS"}  # the compiler settings users get
    start = time.perf_counter()
    subprocess.run(command, check=True, env=env)
    return time.perf_counter() - start


def spin(seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pass


def compare(agent: str, generator: Path, work: Path, attempts: int, budget: int) -> dict:
    """Local once, Ray ``attempts`` times: which Ray stores equal the local one, and how many scores differ."""
    local_s = search(agent, generator, work / "local", "local", budget)
    want = evaluations(work / "local")
    runs = []
    for attempt in range(attempts):
        seconds = search(agent, generator, work / f"ray{attempt}", "ray", budget)
        got = evaluations(work / f"ray{attempt}")
        differing = sum(a != b for a, b in zip(got, want)) + abs(len(got) - len(want))
        runs.append({"identical": got == want, "differing_evaluations": differing, "seconds": round(seconds, 1), "load_average": os.getloadavg()})
        print(f"{agent}: ray attempt {attempt}: identical {got == want} ({differing} of {len(want)} differ), {seconds:.0f} s", flush=True)
    return {"evaluations": len(want), "local_seconds": round(local_s, 1), "ray": runs, "identical": sum(run["identical"] for run in runs)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, default=Path("runs/quick"), help="a reproduce run with racing/generator and racing/agent")
    parser.add_argument("--attempts", type=int, default=5)
    parser.add_argument("--budget", type=int, default=210)
    parser.add_argument("--busy", type=int, default=1, help="processes spinning on the CPU meanwhile")
    args = parser.parse_args()
    generator = require_input(args.run / "racing" / "generator", QUICK_RUN + " --env racing")
    spinners = [multiprocessing.Process(target=spin, args=(24 * 3600,), daemon=True) for _ in range(args.busy)]
    for process in spinners:
        process.start()
    try:
        with tempfile.TemporaryDirectory() as folder:
            work = Path(folder)
            agents = {"driver": "driver", "onnx": str(actor_onnx(args.run / "racing" / "agent", work / "actor.onnx"))}
            results = {name: compare(agent, generator, work / name, args.attempts, args.budget) for name, agent in agents.items()}
    finally:
        for process in spinners:
            process.terminate()
    payload = {
        "command": " ".join(["python", *sys.argv]),
        "campaign": f"search racing --minimize --budget {args.budget} (CMA-ES, 21 worlds x 8 episodes a generation)",
        "busy_processes": args.busy,
        "results": results,
    }
    print(f"wrote {record('ray-identical-stores', payload)}")


if __name__ == "__main__":
    main()
