"""Failures that belong to the world: do other agents fail where one agent's atlas found failures? (issue 39, item 4)

    python benchmarks/studies/transfer_failures.py --generator runs/open/racing/generator \\
        --agents runs/curriculum-racing-open/dr/s{0,1,2,3,4}

For each repair of the generator's VAE (``EnvSpec.repairs``: the paper's ``nearest``, ``open``) and
each agent: a failure atlas (CMA-ME over the env's default descriptors, ``--budget`` worlds,
``--repeats`` episodes each, pushing the failure event's metric towards it: racing's crash rate
up) finds the worlds where the agent meets the env's failure event (racing: ``crash_rate > 0.5``); every distinct failing world is replayed by every other agent
(``--repeats`` episodes, the same keys), and a world *transfers* when at least ``--transfer`` of
the other agents also fail on it. Per repair and agent: failing worlds found, and how many
transfer; the failure matrix (world x agent) is kept, and the transferable worlds are written to
``--out`` (an ``.npz`` of their latents and fields, per repair) for held-out evaluation, and all
agents' failing worlds to ``WORK/failing-REPAIR-EVENT.npz``.

Recorded in ``benchmarks/results/transfer-failures.json`` under ``runs[FAILURE]`` (``--failure``: another
event than the env's, e.g. a lower threshold; the atlases of one event are reused by a rerun).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: machine and the scripts imported
from machine import RESULTS, describe_machine  # noqa: E402
from worldagent import experiments  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.evaluation.local import evaluate  # noqa: E402
from worldagent.events import parse_selection  # noqa: E402
from worldagent.files import write_text  # noqa: E402
from worldagent.search.objectives import generate  # noqa: E402
from worldagent.store import RunStore  # noqa: E402
from worldagent.worlds.generator import build_generator, load_generator  # noqa: E402

REPLAY_SEED = 20_261_128  # the replays' episode keys, apart from the atlas's


def world_key(world) -> str:
    """A hash of one world's arrays: equal for worlds a repair made identical."""
    digest = hashlib.sha256()
    for leaf in jax.tree_util.tree_leaves(world):
        digest.update(np.ascontiguousarray(np.asarray(leaf)).tobytes())
    return digest.hexdigest()


def failing_latents(store, setup, spec, failure: str, budget: int, name: str, progress: bool) -> tuple[np.ndarray, float]:
    """(f32[F, L] latents of the distinct worlds with ``failure`` an atlas of ``budget`` worlds finds on
    the agent, the most extreme world mean of the event's metric it found)."""
    selection = parse_selection(failure, spec.name)
    clause = selection.clauses[0]  # the atlas pushes the event's first metric towards it
    maximize = clause.op in (">", ">=")
    found = experiments.atlas(store, setup, clause.metric, maximize=maximize, budget=budget, seed=0, name=name, progress=progress)["evaluations"]
    extreme = float(max(e.score for e in found) if maximize else min(e.score for e in found))
    failing = np.flatnonzero(selection.mask(found))
    if not len(failing):
        return np.zeros((0, setup.generator.latent_dim), np.float32), extreme
    latents = np.stack([found[i].latent for i in failing])
    worlds = generate(setup.generator, latents)
    keys = [world_key(jax.tree_util.tree_map(lambda leaf, i=i: leaf[i], worlds)) for i in range(len(latents))]
    first = sorted({key: i for i, key in reversed(list(enumerate(keys)))}.values())
    return latents[first].astype(np.float32), extreme


def fails(spec, setup, worlds, repeats: int, failure: str) -> np.ndarray:
    """bool[W]: the event ``failure`` holds on each world's ``repeats`` episodes."""
    metrics = evaluate(setup.env, setup.policy, worlds, repeats, jax.random.key(REPLAY_SEED), setup.params)
    metrics = spec.metrics.with_derived({k: np.asarray(v, np.float64) for k, v in metrics.items()}, setup.params)
    failing = np.ones(len(metrics[spec.metrics.main]), bool)
    for clause in parse_selection(failure, spec.name).clauses:
        failing &= clause.holds(np.asarray(metrics[clause.metric]).mean(axis=1))
    return failing


def one_repair(spec, generator, agents: list[str], args, store) -> tuple[dict, np.ndarray]:
    """Per agent: failing worlds found and transferred, the failure matrix; and the transferable latents."""
    setups = [experiments.setup(spec.name, agent, generator, repeats=args.repeats) for agent in agents]
    found = [
        failing_latents(store, setup, spec, args.failure, args.budget, f"{generator.repair_name}-a{i}", not args.quiet)
        for i, setup in enumerate(setups)
    ]
    per_agent, transferable = [], []
    for i, (latents, extreme) in enumerate(found):
        matrix = np.zeros((len(latents), len(agents)), bool)
        if len(latents):
            worlds = generate(generator, latents)
            for j, setup in enumerate(setups):
                matrix[:, j] = fails(spec, setup, worlds, args.repeats, args.failure)
        others = np.delete(matrix, i, axis=1).sum(axis=1) if len(latents) else np.zeros(0, int)
        transfers = others >= args.transfer
        transferable.append(latents[transfers])
        per_agent.append(
            {
                "agent": agents[i],
                "most_extreme_found": extreme,
                "failing_worlds": int(len(latents)),
                "replayed_failing_by_self": int(matrix[:, i].sum()) if len(latents) else 0,
                "transferable": int(transfers.sum()),
                "others_failing_histogram": np.bincount(others, minlength=len(agents)).tolist(),
                "failure_matrix": matrix.astype(int).tolist(),
            }
        )
        print(f"{generator.repair_name} agent {i}: {len(latents)} failing worlds, {int(transfers.sum())} transfer", flush=True)
    latents = np.concatenate(transferable) if transferable else np.zeros((0, generator.latent_dim), np.float32)
    every = np.concatenate([found_latents for found_latents, _ in found]) if found else latents[:0]
    summary = {
        "agents": per_agent,
        "failing_worlds": sum(a["failing_worlds"] for a in per_agent),
        "transferable": sum(a["transferable"] for a in per_agent),
    }
    return summary, latents, every


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--generator", type=Path, required=True, help="a trained generator; its VAE is repaired each way")
    parser.add_argument("--agents", nargs="+", required=True, help="agent directories (e.g. one per seed)")
    parser.add_argument("--budget", type=int, default=420, help="worlds of each agent's atlas")
    parser.add_argument("--repeats", type=int, default=8)
    parser.add_argument("--transfer", type=int, default=3, help="other agents that must also fail for a world to transfer")
    parser.add_argument("--work", type=Path, default=Path("runs/transfer-failures"))
    parser.add_argument("--out", type=Path, default=None, help="transferable worlds (default: WORK/transferable-REPAIR.npz)")
    parser.add_argument("--failure", default=None, help="the event that counts as failing (default: the env's failure event)")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args()
    _, vae, dataset = load_generator(args.generator)
    spec = registry.get(dataset.env)
    args.failure = args.failure or spec.failure
    result = {
        "env": spec.name,
        "generator": str(args.generator),
        "agents": args.agents,
        "failure": args.failure,
        "budget": args.budget,
        "repeats": args.repeats,
        "transfer_threshold": f">= {args.transfer} of the other {len(args.agents) - 1} agents also fail",
        "repairs": {},
    }
    args.work.mkdir(parents=True, exist_ok=True)
    for name in spec.repair_names:
        generator = build_generator(vae, dataset, repair_name=name)
        with RunStore(args.work / f"atlas-{name}.sqlite") as store:
            summary, latents, every = one_repair(spec, generator, args.agents, args, store)
        event = args.failure.replace(" ", "")
        np.savez(args.work / f"failing-{name}-{event}.npz", latents=every)  # every agent's, for a held-out set
        out = args.out or args.work / f"transferable-{name}-{event}.npz"
        worlds = generate(generator, latents) if len(latents) else None
        fields = {f"world/{k}": np.asarray(v) for k, v in (vars(worlds).items() if worlds is not None else [])}
        np.savez(out, latents=latents, **fields)
        result["repairs"][name] = {**summary, "transferable_worlds_file": str(out)}
    result["machine"] = describe_machine()
    result["command"] = "python benchmarks/studies/transfer_failures.py " + " ".join(sys.argv[1:])
    path = RESULTS / "transfer-failures.json"
    runs = json.loads(path.read_text()).get("runs", {}) if path.is_file() else {}
    runs[args.failure] = result  # one entry per failure event: a lower threshold says how near the default came
    write_text(path, json.dumps({"runs": runs}, indent=1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
