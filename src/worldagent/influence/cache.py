"""What an influencing run caches in its directory, and the checks that keep the cache honest.

An influence run (``influence.experiment.influence``) is slow, so every step is cached in its
run directory and a rerun skips finished work. The cache is only reused for the same settings:
``plan.json`` records them per stage and a rerun with other ones is refused (one line naming
``--out``), instead of silently mixing two experiments.

    plan.json                the settings each stage's cached work was made with
    influenced_worlds.npz    the new training distribution (worlds, latents, metric values)
    agents/<label>-s<seed>/trained.json   marks a finished agent
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.files import write_atomically, write_text
from worldagent.provenance import fingerprint  # noqa: F401  (campaign and influence caches share it)

PLAN_FILE = "plan.json"
WORLDS_FILE = "influenced_worlds.npz"
TRAINED_FILE = "trained.json"


def config_dict(config: Any) -> dict:
    """A training config (a dataclass) as JSON-able fields."""
    if hasattr(config, "to_dict"):
        return config.to_dict()
    return json.loads(json.dumps(dataclasses.asdict(config), default=str))


def check_plan(run_dir: Path, stage: str, settings: dict, record: bool = True) -> None:
    """Record the settings one stage's cached work is made with (``plan.json``), or refuse a run
    dir whose cached work of that stage was made with other settings.

    Two stages: "worlds" (the candidates: agent, G, env params, counts, seed; checked first) and
    "training" (the selection, its confirmation, algorithm and budget; recorded only once a selection
    matched, so a selection that matched nothing can be loosened and rerun in the same directory;
    ``record`` False only checks it, before work such as a confirmation that another plan would waste).
    """
    path = run_dir / PLAN_FILE
    try:
        plan = json.loads(path.read_text()) if path.is_file() else {}
    except ValueError:
        raise WorldagentError(f"{path} is not valid JSON; delete it or use another output directory.") from None
    wanted = json.loads(json.dumps(settings))  # compare as stored: tuples become lists
    previous = plan.get(stage, wanted)
    differing = sorted(k for k in wanted.keys() | previous.keys() if previous.get(k) != wanted.get(k))
    if differing:
        raise WorldagentError(
            f"{run_dir} holds an influence run made with other settings ({', '.join(differing)}); "
            "rerun with the same ones or use another output directory (--out)."
        )
    if record and stage not in plan:
        write_text(path, json.dumps({**plan, stage: settings}, indent=1, sort_keys=True))


def save_influenced_worlds(path: Path, spec, worlds: Any, latents: np.ndarray, values: dict[str, np.ndarray]) -> Path:
    """The influenced distribution as ``.npz``: ``world_<field>`` arrays, ``latents``, ``value_<metric>``.

    Args:
        path: the file to write (atomically).
        spec: the env's ``EnvSpec`` (or name): how its worlds become arrays.
        worlds: k worlds (a batched world pytree); ``latents`` f64[k, dim]; ``values`` {metric: f64[k]}.
    """
    arrays = {f"world_{k}": v for k, v in registry.get(spec).world_to_arrays(worlds).items()}
    arrays.update({"latents": np.asarray(latents)}, **{f"value_{k}": np.asarray(v) for k, v in values.items()})

    def save(tmp: Path) -> None:
        with open(tmp, "wb") as handle:
            np.savez_compressed(handle, **arrays)

    return write_atomically(path, save)


def load_influenced_worlds(run_dir: str | Path, env, name: str = WORLDS_FILE) -> tuple[Any, np.ndarray, dict[str, np.ndarray]]:
    """(worlds [k], latents f64[k, dim], {metric: f64[k]}) of a run's influenced distribution.

    Args:
        run_dir: the influence run directory (or a later round's, ``round-<r>/``).
        env: the env's name or ``EnvSpec`` (the worlds' fields are checked against its world type).
        name: the file (a later round's: ``rounds.worlds_file(seed)``).
    """
    spec = registry.get(env)
    path = Path(run_dir) / name
    if not path.is_file():
        raise WorldagentError(f"{path} does not exist; run `worldagent influence` into {run_dir} first.")
    with np.load(path, allow_pickle=False) as data:
        world = {k[len("world_") :]: data[k] for k in data.files if k.startswith("world_")}
        values = {k[len("value_") :]: data[k] for k in data.files if k.startswith("value_")}
        latents = data["latents"]
    fields = sorted(f.name for f in dataclasses.fields(spec.world_type))
    if sorted(world) != fields:
        raise WorldagentError(f"{path} holds no {spec.name} worlds; pass the environment the run was made for.")
    return spec.world_from_arrays(world), latents, values
