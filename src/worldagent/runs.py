"""One reader of a ``worldagent reproduce`` run directory, for the HTML report and the explorer.

A run directory holds ``manifest.json`` (the preset, versions, and every phase's status, config
and outputs; ``reproduce/manifest.py`` writes it) and, per environment, what its phases wrote::

    <run>/<env>/
        dataset.npz            the procedurally generated worlds (paper §5.2.1)
        generator/             the VAE and G(z) (quality.json: its quality figures)
        agent/                 the training run (checkpoint, curve.csv/png, the saved agent in policy/; with an
                               adaptive curriculum its buffer snapshots in curriculum/ and curriculum.png)
        store.sqlite           random / strategic (min, max) / comparison / atlas / failure-rate campaigns
        influence/             the influencing experiment (influence.json, its agents)
        figures/               figures drawn by phases and the report (strategic.png, ..., curriculum.png)

``RunLayout`` says where each of those lives; ``Run`` reads them: the manifest, each phase's
record, the store's evaluations and worlds, the generator and the agent. It sits below
``reproduce/`` (which writes runs), ``reports/`` and ``explore/`` (which read them), so neither
reader imports the writer. It never writes.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from worldagent.errors import WorldagentError

PHASES = ("dataset", "generator", "agent", "random", "strategic", "compare", "influence", "atlas")
MANIFEST_FILE = "manifest.json"
MANIFEST_FORMAT = 1


@dataclass(frozen=True)
class RunLayout:
    """The paths of one environment's part of a run directory.

    Attributes:
        run_dir: the run directory.
        env: the registered environment's name.
    """

    run_dir: Path
    env: str

    @property
    def dir(self) -> Path:
        return Path(self.run_dir) / self.env

    @property
    def dataset_path(self) -> Path:
        return self.dir / "dataset.npz"

    @property
    def generator_dir(self) -> Path:
        return self.dir / "generator"

    @property
    def quality_path(self) -> Path:
        return self.generator_dir / "quality.json"

    @property
    def agent_dir(self) -> Path:
        return self.dir / "agent"

    @property
    def store_path(self) -> Path:
        return self.dir / "store.sqlite"

    @property
    def influence_dir(self) -> Path:
        return self.dir / "influence"

    @property
    def influence_result(self) -> Path:
        return self.influence_dir / "influence.json"

    @property
    def figures(self) -> Path:
        return self.dir / "figures"

    def figure(self, name: str) -> Path:
        """``figures/<name>.png`` (traversals, random, strategic, comparison, influence)."""
        return self.figures / f"{name}.png"

    def rel(self, path: Path) -> str:
        """``path`` relative to the run directory (the run directory may be moved)."""
        return str(Path(path).relative_to(self.run_dir))

    def phase_outputs(self) -> dict[str, list[Path]]:
        """The files and folders each phase writes (removed when ``--restart`` redoes it)."""
        return {
            "dataset": [self.dataset_path],
            "generator": [self.generator_dir, self.figure("generator_traversals")],
            "agent": [self.agent_dir, self.figure("curriculum")],
            "strategic": [self.figure("strategic")],
            "compare": [self.figure("comparison")],
            "influence": [self.influence_dir, self.figure("influence")],
            "atlas": [self.figure("atlas"), self.figure("atlas_counterfactuals")],
        }


def parse_manifest(path: Path) -> dict:
    """The checked contents of a ``manifest.json`` file; one-line errors for unreadable or foreign files."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        raise WorldagentError(f"{path} is not readable JSON; delete it to start the run afresh, or pick another --out.") from None
    if not isinstance(data, dict) or data.get("format_version") != MANIFEST_FORMAT or not isinstance(data.get("phases"), dict):
        raise WorldagentError(f"{path} is not a worldagent reproduce manifest (format {MANIFEST_FORMAT}); pick another --out.")
    return data


def read_manifest(run_dir: Path | str) -> dict:
    """The manifest of an existing run directory; refuses a directory without one."""
    path = Path(run_dir) / MANIFEST_FILE
    if not path.is_file():
        raise WorldagentError(f"{run_dir} has no {MANIFEST_FILE}; run `worldagent reproduce --out {run_dir}` first.")
    return parse_manifest(path)


def read_json(path: Path) -> dict | None:
    """A JSON file's contents, None when it is absent."""
    return json.loads(path.read_text()) if path.is_file() else None


@dataclass(frozen=True)
class Parts:
    """One environment given piece by piece instead of as a ``reproduce`` directory.

    Attributes:
        store: a ``store.sqlite``.
        generator: a generator directory (``worldagent generator train``); its recorded dataset.
        agent: what ``agents.loaders.load_agent`` reads (a train run, a scripted name, ...), or None.
    """

    store: Path
    generator: Path
    agent: str | None = None


@dataclass(frozen=True)
class Run:
    """A run as its readers see it: a ``reproduce`` directory (``Run.open``) or parts (``Run.of_parts``).

    Attributes:
        run_dir: the run directory (for parts: the store's folder).
        manifest: its ``manifest.json`` (for parts: one naming the environment, no phases).
        parts: {env: ``Parts``} when the run was given piece by piece.
    """

    run_dir: Path
    manifest: dict
    parts: dict = field(default_factory=dict)

    @classmethod
    def open(cls, run_dir: Path | str) -> Run:
        """Read ``run_dir``'s manifest (refused without one)."""
        return cls(Path(run_dir), read_manifest(run_dir))

    @classmethod
    def of_parts(cls, store: Path | str, generator: Path | str, agent: str | None = None, env: str | None = None) -> Run:
        """A run of one environment from a store, a generator and (optionally) an agent; ``env``
        defaults to the generator's."""
        store, generator = Path(store), Path(generator)
        if not store.is_file():
            raise WorldagentError(f"no run store at {store}; pass the store.sqlite a campaign wrote (--store).")
        recorded = read_json(generator / "generator.json") if generator.is_dir() else None
        if recorded is None:
            raise WorldagentError(f"{generator} holds no generator; pass a directory `worldagent generator train` wrote (--generator).")
        env = env or recorded.get("env")
        if recorded.get("env") != env:
            raise WorldagentError(f"the generator in {generator} makes {recorded.get('env')} worlds, not {env} worlds; pass a {env} generator.")
        manifest = {"format_version": MANIFEST_FORMAT, "envs": [env], "phases": {}, "preset": None}
        return cls(store.parent, manifest, {env: Parts(store, generator, agent)})

    @property
    def envs(self) -> list[str]:
        """The registered environments the run names, in the order they ran."""
        from worldagent.envs import registry

        return [env for env in self.manifest.get("envs", []) if env in registry.names()]

    def require_envs(self) -> list[str]:
        """``envs``, refusing a run that names none."""
        if not self.envs:
            raise WorldagentError(f"{self.run_dir}/{MANIFEST_FILE} names no environment; run `worldagent reproduce --out {self.run_dir}` first.")
        return self.envs

    def layout(self, env: str) -> RunLayout:
        return RunLayout(self.run_dir, env)

    # -- phases ---------------------------------------------------------------------------------

    def phases(self, env: str) -> dict[str, dict]:
        """{phase: its manifest record ({} when it never ran)} for every phase of ``PHASES``."""
        recorded = self.manifest.get("phases", {})
        return {name: recorded.get(f"{env}/{name}", {}) for name in PHASES}

    def done(self, env: str, phase: str) -> bool:
        return self.phases(env)[phase].get("status") == "done"

    def outputs(self, env: str, phase: str) -> dict:
        """What a finished phase recorded ({} when it has not finished)."""
        entry = self.phases(env)[phase]
        return entry.get("outputs", {}) if entry.get("status") == "done" else {}

    # -- files ----------------------------------------------------------------------------------

    def quality(self, env: str) -> dict | None:
        """The generator's ``quality.json``."""
        return read_json(self.layout(env).quality_path)

    def influence(self, env: str) -> dict | None:
        """``influence.json`` of a finished influence phase."""
        return read_json(self.layout(env).influence_result) if self.done(env, "influence") else None

    def curriculum(self, env: str) -> dict | None:
        """What the agent phase's curriculum was and did, None before that phase finished (and for parts):

        - ``request``: its recorded config (``Preset.curriculum_of``: name, settings, target), None for ``dr``;
        - ``label``: as the agent's ``run.json`` records it (``curricula.label``: ``"dr"``, or the name and every setting);
        - ``snapshots``: the buffer at every checkpoint (``curricula.snapshots.load_snapshots``; [] for ``dr``);
        - ``favoured``: the last snapshot's favoured worlds as confirmed on fresh episodes, read back from the store
          with the random campaign's failure rate as baseline (``analysis.favoured.read_favoured``); None when the
          agent phase confirmed none (``dr``, runs from before confirmation).
        """
        if env in self.parts or not self.done(env, "agent"):
            return None
        from worldagent.curricula.snapshots import load_snapshots

        request = self.phases(env)["agent"].get("config", {}).get("curriculum")
        label = self.outputs(env, "agent").get("curriculum", "dr" if request is None else request["name"])  # runs before the field: dr
        snapshots, record, favoured = load_snapshots(self.layout(env).agent_dir), self.outputs(env, "agent").get("favoured"), None
        if record and snapshots and self.has_store(env):
            from worldagent.analysis.favoured import read_favoured
            from worldagent.envs import registry

            randoms = self.random_campaign(env)
            with self.store(env) as store:
                favoured = read_favoured(store, registry.get(env), snapshots[-1], record, store.evaluations(randoms) if randoms else None)
        return {"request": request, "label": label, "snapshots": snapshots, "favoured": favoured}

    def store_path(self, env: str) -> Path:
        return self.parts[env].store if env in self.parts else self.layout(env).store_path

    def has_store(self, env: str) -> bool:
        return self.store_path(env).exists()

    def store(self, env: str):
        """The environment's ``RunStore`` (a context manager; refused when there is none)."""
        from worldagent.store import RunStore

        return RunStore(self.store_path(env), create=False)

    def evaluations(self, env: str) -> list:
        """Every evaluation of the environment's store (without worlds), campaign by campaign."""
        if not self.has_store(env):
            return []
        with self.store(env) as store:
            return store.evaluations()

    def random_campaign(self, env: str) -> str | None:
        """The env's random evaluation (paper §6.1.1): the random phase's campaign, else the first stored campaign
        named as `worldagent evaluate random` names one (``experiments.random_campaign_name``); None without one."""
        recorded = self.outputs(env, "random").get("campaign")
        if recorded or not self.has_store(env):
            return recorded
        from worldagent.experiments import random_campaign_name

        with self.store(env) as store:
            campaigns = store.campaigns()
        return next((c.name for c in campaigns if c.optimiser == "random" and c.name == random_campaign_name(c.objective, c.seed)), None)

    def world(self, env: str, campaign: str, generation: int, slot: int) -> Any:
        """The stored world of one evaluation, as the env's world type (unbatched)."""
        from worldagent.envs import registry

        with self.store(env) as store:
            arrays = store.world(campaign, generation, slot)
        return registry.get(env).world_from_arrays(arrays)

    def has_generator(self, env: str) -> bool:
        return env in self.parts or self.layout(env).generator_dir.is_dir()

    def generator(self, env: str):
        """G(z) of the run (``worlds.generator.Generator``), with the run's dataset (for parts: the generator's own)."""
        from worldagent.worlds.generator import load_generator

        if env in self.parts:
            return load_generator(self.parts[env].generator)[0]
        layout = self.layout(env)
        return load_generator(layout.generator_dir, layout.dataset_path)[0]

    def agent_source(self, env: str) -> str | None:
        """What ``load_agent`` reads for the run's own agent; None before the agent phase finished."""
        if env in self.parts:
            return self.parts[env].agent
        return str(self.layout(env).agent_dir) if self.done(env, "agent") else None
