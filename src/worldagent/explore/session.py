"""The explorer's state over one run: each environment's stored worlds, its G(z) and its agents.

``Session.open(run_dir)`` reads the run through ``runs.Run``: every evaluation of every store
(without worlds; a world is read from the store when asked for), their latents, projection and
metric means. Generators and agents load on first use and stay loaded; every JAX call of an
environment holds that environment's lock, so concurrent requests never compile one program
twice. A play superseded by a newer one from the same page while it waited for that lock is
dropped unplayed (``Superseded``). Episodes are played in batches of ``EPISODE_BUCKETS`` (the
first ``episodes`` kept), so each agent compiles at most twice. Agents are chosen by label from ``EnvSession.agents``, a fixed list built here (the run's
agent, the influence phase's agents, the env's scripted ones): a request never names a path.
"""

from __future__ import annotations

import io
import threading
from collections import Counter, OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.events import parse_selection
from worldagent.explore import views
from worldagent.explore.diff import diff_agents, diff_campaigns, diff_view
from worldagent.explore.episodes import episodes_payload, picture_key, replay_marked
from worldagent.runs import Run

RUN_AGENT = "run"  # the label of the run's own trained agent
PICTURE_CACHE = 2048  # stored worlds' PNGs kept (a 160 px picture is a few kB)
# G(z) decodes two latents at a time, the second a dummy: on CPU, XLA runs a nearest-world repair's
# product with the dataset ~12x slower for one row than for two (racing quick: 390 ms against 33 ms).
DECODE_ROWS = 2
SAME_LATENT = 1e-9  # latents closer than this are one world (scored again by another campaign), never its own neighbour
NEIGHBOURS_READ = 16  # a failing world's nearest passing candidates whose worlds are read at a time (the same world is skipped)
# A play's episodes are replayed in one of these batch sizes (the first ones kept): the replay compiles per
# batch size and agent, so 1-16 episodes cost at most two compiles an agent instead of sixteen.
EPISODE_BUCKETS = (8, 16)


class Superseded(Exception):
    """A play that a newer one from the same page replaced before it started: not played."""


def episode_bucket(episodes: int) -> int:
    """The batch size ``episodes`` episodes are replayed in (``EPISODE_BUCKETS``; larger counts as asked)."""
    return next((b for b in EPISODE_BUCKETS if b >= episodes), int(episodes))


def agent_sources(run: Run, env: str) -> dict[str, str]:
    """{label: what ``agents.loaders.load_agent`` reads} of every agent the explorer may play."""
    spec = registry.get(env)
    own = run.agent_source(env)
    found = {RUN_AGENT: own} if own else {}
    agents_dir = run.layout(env).influence_dir / "agents"
    if agents_dir.is_dir():
        found |= {f"influence/{d.name}": str(d) for d in sorted(agents_dir.iterdir()) if (d / "policy").is_dir()}
    found |= diff_agents(diff_campaigns(run, env))  # the two agents of each `worldagent diff` in the store
    return found | {f"scripted/{name}": name for name in spec.scripted}


def png_bytes(image) -> bytes:
    buffer = io.BytesIO()
    image.save(buffer, format="PNG")
    return buffer.getvalue()


@dataclass
class EnvSession:
    """One environment of the run, as the explorer serves it.

    Attributes:
        run: the run; env: the environment's name.
        evaluations: every stored evaluation (no worlds), campaign by campaign.
        latents: f64[n, d]; xy: f64[n, 2] their projection; means: {metric: f64[n]}.
        agents: {label: source} (``agent_sources``).
    """

    run: Run
    env: str
    evaluations: list
    latents: np.ndarray
    projection: views.Projection
    xy: np.ndarray
    means: dict[str, np.ndarray]
    agents: dict[str, str]
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    ready: set = field(default_factory=set, repr=False)  # (agent, batch size) compiled: its plays answer at once
    warming: str | None = None  # the agent the warm-up is compiling now
    cache_lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    pictures: OrderedDict = field(default_factory=OrderedDict, repr=False)
    counts: dict = field(default_factory=dict, repr=False)  # {campaign: evaluations stored} when last read (``rescan``)
    scan_lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    _loaded: dict = field(default_factory=dict, repr=False)

    @classmethod
    def open(cls, run: Run, env: str) -> EnvSession:
        spec = registry.get(env)
        counts = stored_counts(run, env)  # before the evaluations: what is added between is read twice, never missed
        stored = [e for e in run.evaluations(env) if len(e.latent)]
        dim = run_latent_dim(run, env, stored)
        evaluations = [e for e in stored if len(e.latent) == dim]  # a store searched with another generator keeps its own latents
        latents = np.stack([e.latent for e in evaluations]).astype(np.float64) if evaluations else np.zeros((0, dim))
        projection = views.principal_projection(latents if len(latents) else np.zeros((1, dim)))
        names = views.scalar_metrics(evaluations, spec.metrics.names)
        means = views.metric_table(evaluations, names)
        return cls(run, env, evaluations, latents, projection, projection(latents), means, agent_sources(run, env), counts=counts)

    @property
    def spec(self):
        return registry.get(self.env)

    @property
    def latent_dim(self) -> int:
        return int(self.latents.shape[1])

    def rescan(self) -> int:
        """Read the evaluations the store gained since it was last read (a `worldagent diff` written into the
        run while the explorer serves it, a campaign still running) and the agents they name; returns how many.

        Cheap when nothing changed (one count per campaign). New evaluations are appended: every stored world
        keeps its index (a page's map and links stay right) and the map's projection stays as it was.
        """
        with self.scan_lock:
            counts = stored_counts(self.run, self.env)
            grown = [name for name, count in counts.items() if count > self.counts.get(name, 0)]
            if not grown:
                return 0
            known = {(e.campaign, e.generation, e.slot) for e in self.evaluations}
            with self.run.store(self.env) as store:
                read = [e for name in grown for e in store.evaluations(name)]
            added = [e for e in read if (e.campaign, e.generation, e.slot) not in known and len(e.latent) == self.latent_dim]
            self.counts = counts
            self._forget_agents(agent_sources(self.run, self.env))
            for key in ("index", "atlas_names", "share"):  # read again when next asked
                self._loaded.pop(key, None)
            if added:
                latents = np.stack([e.latent for e in added]).astype(np.float64)
                more = views.metric_table(added, list(self.means))
                # arrays first, the list of evaluations last: a request reading meanwhile sees the old worlds whole
                self.means = {name: np.concatenate([values, more[name]]) for name, values in self.means.items()}
                self.latents = np.concatenate([self.latents, latents])
                self.xy = np.concatenate([self.xy, self.projection(latents)])
                self.evaluations = self.evaluations + added
            return len(added)

    def _forget_agents(self, agents: dict[str, str]) -> None:
        """Take ``agents`` as the agent list; a label that now names another agent is loaded (and compiled) again."""
        changed = {label for label, source in self.agents.items() if agents.get(label) != source}
        for label in changed:
            self._loaded.pop(f"agent:{label}", None)
        self.ready = {(agent, bucket) for agent, bucket in self.ready if agent not in changed}
        self.agents = agents

    def describe(self) -> dict:
        """What the page needs to lay out this environment's views (read after ``rescan``: a reload shows what the store gained)."""
        self.rescan()
        spec = self.spec
        selection = parse_selection(spec.failure, self.env) if spec.failure else None
        return {
            "name": self.env,
            "latent_dim": self.latent_dim,
            "worlds": len(self.evaluations),
            "metrics": list(self.means),
            "meanings": {name: spec.metrics.meanings[name] for name in self.means if name in spec.metrics.meanings},
            "main": spec.metrics.main if spec.metrics.main in self.means else next(iter(self.means), None),
            "highlighted": [m for m in spec.metrics.highlighted if m in self.means],
            "failure": spec.failure,
            "agents": list(self.agents),
            "has_generator": self.run.has_generator(self.env),
            "animates": spec.pictures.locate is not None,
            "thresholds": views.thresholds(selection, list(self.means)) if selection else {},
            "worse": views.worse_ends(selection, self.atlas_ends(), list(self.means)),
            "key": picture_key(spec.pictures),
            "atlases": self.atlas_names(),
            "diffs": list(diff_campaigns(self.run, self.env)),
            "campaign_words": self.campaign_words(),
        }

    def campaign_words(self) -> dict[str, str]:
        """{campaign: what it is, in words} of every campaign in the store (``search.names.describe_campaign``,
        from its recorded config), in store order."""
        from worldagent.search.names import describe_campaign

        if not self.run.has_store(self.env):
            return {}
        with self.run.store(self.env) as store:
            return {c.name: describe_campaign(c, c.name) for c in store.campaigns()}

    # -- stored worlds --------------------------------------------------------------------------

    def evaluation(self, index: int):
        if not 0 <= index < len(self.evaluations):
            raise WorldagentError(f"world {index} is not stored; pick one of 0..{len(self.evaluations) - 1}.")
        return self.evaluations[index]

    def stored_world(self, index: int) -> Any:
        """Stored world ``index``; campaigns that kept no worlds (failure-rate estimates) evaluated G(z), so it is decoded."""
        found = self.evaluation(index)
        try:
            return self.run.world(self.env, found.campaign, found.generation, found.slot)
        except WorldagentError:
            return self.decode(found.latent)

    def index_of(self, campaign: str, generation: int, slot: int) -> int:
        if "index" not in self._loaded:
            self._loaded["index"] = {(e.campaign, e.generation, e.slot): i for i, e in enumerate(self.evaluations)}
        return self._loaded["index"][(campaign, int(generation), int(slot))]

    def world_summary(self, index: int) -> dict:
        found = self.evaluation(index)
        return {
            "index": index,
            "campaign": found.campaign,
            "generation": found.generation,
            "slot": found.slot,
            "latent": [round(float(v), 5) for v in found.latent],
            "score": finite_or_none(found.score),
            "episodes": len(found.episodes),
            "metrics": {name: finite_or_none(values[index]) for name, values in self.means.items()},
            "log_prior": float(views.log_prior(found.latent[None])[0]),
        }

    # -- the map, the failures, the atlas ---------------------------------------------------------

    def map_data(self) -> dict:
        """Every stored world's place, campaign and metric means; which fail the env's failure event; the
        projection (its axes and the share of variance each shows)."""
        campaigns = list(dict.fromkeys(e.campaign for e in self.evaluations))
        order = {name: i for i, name in enumerate(campaigns)}
        failure = self.failing(None, required=False)
        return {
            "x": rounded(self.xy[:, 0]),
            "y": rounded(self.xy[:, 1]),
            "campaigns": campaigns,
            "campaign": [order[e.campaign] for e in self.evaluations],
            "markers": views.campaign_markers(len(campaigns)),
            "distinct_markers": len(views.MARKERS),
            "metrics": {name: rounded(values) for name, values in self.means.items()},
            "axes": rounded(self.projection.axes),
            "centre": rounded(self.projection.centre),
            "explained": rounded(self.projection.explained),
            "failure": failure[0].describe() if failure else None,
            "failing": failure[1].astype(int).tolist() if failure else None,
            "share": self.world_share(),
        }

    def world_share(self) -> dict | None:
        """The world's share of the main metric and of the failure event over the stored random campaign
        (``reports.results.world_share_summary``; no episode is played), with its one line; None without one."""
        if "share" not in self._loaded:
            self._loaded["share"] = self._read_share()
        return self._loaded["share"]

    def _read_share(self) -> dict | None:
        from worldagent.analysis.noise import share_line
        from worldagent.reports.results import world_share_summary

        campaign = self.run.random_campaign(self.env)
        if campaign is None:
            return None
        with self.run.store(self.env) as store:
            evaluations = store.evaluations(campaign)
        main = self.spec.metrics.main
        summary = world_share_summary(self.spec, evaluations, [main])
        if not summary:
            return None
        line = f"{campaign}, {summary['worlds']:,} worlds x {summary['repeats']} episodes: {share_line(summary, main)}"
        return {"campaign": campaign, "line": line, "summary": summary}

    def failing(self, event: str | None, required: bool = True):
        """(selection, bool[n] which stored worlds it selects) of ``event`` (default: the env's failure);
        None when there is no event or (not ``required``) the stored worlds lack its metrics."""
        text = event or self.spec.failure
        if not text:
            if not required:
                return None
            raise WorldagentError(f"{self.env} names no failure event; pass one, e.g. event={next(iter(self.means), 'metric')} < 0.")
        selection = parse_selection(text, self.env)
        missing = [m for m in selection.metrics if m not in self.means]
        if missing:
            if not required:
                return None
            raise WorldagentError(f"the stored worlds have no per-episode {missing[0]!r}; use one of: {', '.join(self.means)}.")
        return selection, selection.mask(self.evaluations) if self.evaluations else np.zeros(0, bool)

    def failures(self, event: str | None, by: str, limit: int) -> dict:
        """The failing stored worlds ranked ``by`` likelihood or severity, each with its nearest passing world."""
        selection, failing = self.failing(event)
        severity = views.severity(selection, self.means)
        order = views.rank_failures(self.latents, failing, severity, by)
        ranked, repeats = views.distinct_worlds(self.world_keys(order), order)
        distinct = len(ranked)
        ranked, repeats = ranked[:limit], repeats[:limit]
        passing = np.flatnonzero(~failing)
        near, distance = self.nearest_other_worlds(ranked, passing)
        prior = views.log_prior(self.latents[ranked])
        rows = [
            {
                "index": int(i),
                "campaign": self.evaluations[i].campaign,
                "log_prior": float(prior[k]),
                "severity": float(severity[i]),
                "metrics": {name: finite_or_none(self.means[name][i]) for name in selection.metrics},
                "evaluations": int(repeats[k]),
                "nearest_passing": int(near[k]) if near[k] >= 0 else None,
                "nearest_metrics": {name: finite_or_none(self.means[name][near[k]]) for name in selection.metrics} if near[k] >= 0 else None,
                "distance": finite_or_none(distance[k]),
            }
            for k, i in enumerate(ranked)
        ]
        return {
            "event": selection.describe(),
            "failing": int(failing.sum()),
            "distinct": distinct,
            "worlds": len(self.evaluations),
            "by": by,
            "rows": rows,
        }

    def world_keys(self, indices) -> list[str]:
        """The identity of each stored evaluation's repaired world (``store.world_digest``, DESIGN.md "Identity"):
        latents that repair to one world are one world. Read once and kept; a campaign that stored no worlds
        (failure-rate estimates) is decoded through G(z), and without a generator its latent stands in."""
        known = self._loaded.setdefault("world_keys", {})
        wanted = list(dict.fromkeys(int(i) for i in indices if int(i) not in known))
        if wanted:
            known.update(self._digests(wanted))
        return [known[int(i)] for i in indices]

    def _digests(self, indices: list[int]) -> dict[int, str]:
        from worldagent.store import world_digest

        found, unstored = {}, []
        with self.run.store(self.env) as store:
            for i in indices:
                e = self.evaluations[i]
                try:
                    found[i] = world_digest(store.world(e.campaign, e.generation, e.slot))
                except WorldagentError:
                    unstored.append(i)
        if unstored and self.run.has_generator(self.env):
            from worldagent.search.objectives import generate

            with self.lock:
                worlds = generate(self.generator()[0], self.latents[unstored])
            for k, i in enumerate(unstored):
                world = jax_row(worlds, k)
                found[i] = world_digest(self.spec.world_to_arrays(world))
        elif unstored:
            found |= {i: "latent:" + np.round(self.latents[i], 9).tobytes().hex() for i in unstored}
        return found

    def nearest_other_worlds(self, rows: np.ndarray, candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(stored index, latent distance) of the candidate nearest each of ``rows`` in z that is another repaired
        world (``world_keys``; a latent within ``SAME_LATENT`` is the same one); (-1, inf) where none is."""
        near, distance = np.full(len(rows), -1), np.full(len(rows), np.inf)
        for k, i in enumerate(rows):
            gaps = np.linalg.norm(self.latents[candidates] - self.latents[i], axis=1)
            (own,) = self.world_keys([i])
            order = np.argsort(gaps, kind="stable")
            order = order[gaps[order] > SAME_LATENT]
            for start in range(0, len(order), NEIGHBOURS_READ):  # the nearest few first: most of the time the first one is another world
                chunk = order[start : start + NEIGHBOURS_READ]
                other = next((j for j, key in zip(chunk, self.world_keys(candidates[chunk])) if key != own), None)
                if other is not None:
                    near[k], distance[k] = candidates[other], gaps[other]
                    break
        return near, distance

    def atlas_names(self) -> list[str]:
        if "atlas_names" not in self._loaded:
            from worldagent.search.atlas import atlas_names

            names = []
            if self.run.has_store(self.env):
                with self.run.store(self.env) as store:
                    names = atlas_names(store)
            self._loaded["atlas_names"] = names
        return self._loaded["atlas_names"]

    def atlas_ends(self) -> list[tuple[str, bool]]:
        """(metric, maximize) of each atlas campaign: the end of its metric it searched for."""
        if not self.atlas_names():
            return []
        with self.run.store(self.env) as store:
            found = [store.campaign(name) for name in self.atlas_names()]
        return [(c.objective, bool(c.maximize)) for c in found if c is not None]

    def atlas(self, name: str | None) -> dict:
        """The atlas campaign ``name`` (default: the first) as heat-map cells, each with its worst world."""
        names = self.atlas_names()
        if not names:
            raise WorldagentError(f"the {self.env} store holds no atlas; run `worldagent reproduce` with an atlas budget, or `worldagent atlas`.")
        name = name or names[0]
        if name not in names:
            raise WorldagentError(f"no atlas {name!r}; atlases of {self.env}: {', '.join(names)}.")
        key = f"atlas:{name}"
        with self.lock:
            if key not in self._loaded:
                self._loaded[key] = self._read_atlas(name)
        return self._loaded[key]

    def _read_atlas(self, name: str) -> dict:
        from worldagent.search.atlas import read_atlas

        with self.run.store(self.env) as store:
            atlas = read_atlas(store, name)
        archive, grid = atlas.archive, atlas.grid
        cells = views.atlas_cells(archive.cells, grid.cells, archive.scores, atlas.maximize)
        for cell in cells:
            best = atlas.evaluations[int(archive.best[cell.pop("entry")])]
            cell["world"] = self.index_of(best.campaign, best.generation, best.slot)
        return {
            "name": name,
            "descriptors": list(grid.descriptors[:2]),
            "size": [int(grid.cells[0]), int(grid.cells[1]) if len(grid.cells) > 1 else 1],
            "ranges": [list(map(float, r)) for r in grid.ranges[:2]],
            "metric": atlas.campaign.objective,
            "maximize": atlas.maximize,
            "cells": cells,
        }

    def diff(self, campaign: str | None, event: str | None, limit: int) -> dict:
        """A diff campaign's regressed worlds (``explore.diff.diff_view``), with any diff written since the last request."""
        self.rescan()
        return diff_view(self, campaign, event, limit)

    # -- G(z) and the agents ---------------------------------------------------------------------

    def generator(self):
        if "generator" not in self._loaded:
            import jax

            generator = self.run.generator(self.env)
            self._loaded["generator"] = (generator, jax.jit(lambda g, z: g(z)))
        return self._loaded["generator"]

    def check_latent(self, z) -> np.ndarray:
        z = np.asarray(z, np.float64)
        if z.shape != (self.latent_dim,):
            raise WorldagentError(f"a {self.env} latent has {self.latent_dim} numbers, not {z.size}.")
        return z

    def decode(self, z, superseded: Callable[[], bool] = lambda: False) -> Any:
        """The world G(z) (unbatched) of one latent; ``superseded`` as in ``play`` (a superseded play decodes nothing)."""
        import jax

        z = self.check_latent(z)
        with self.lock:
            if superseded():
                raise Superseded
            generator, decode = self.generator()
            rows = np.zeros((DECODE_ROWS, self.latent_dim), np.float32)
            rows[0] = z
            worlds = decode(generator, rows)
            return jax.tree_util.tree_map(lambda leaf: np.asarray(leaf[0]), worlds)

    def picture(self, world: Any, size: int) -> bytes:
        return png_bytes(self.spec.pictures.world(world, size).convert("RGB"))

    def stored_picture(self, index: int, size: int) -> bytes:
        """PNG of stored world ``index``, kept for the next ask (maps and tables show the same worlds again and again)."""
        key = (index, size)
        with self.cache_lock:  # requests run in threads: one of them at a time reorders the cache
            found = self.pictures.get(key)
            if found is not None:
                self.pictures.move_to_end(key)
                return found
        picture = self.picture(self.stored_world(index), size)
        with self.cache_lock:
            self.pictures[key] = picture
            while len(self.pictures) > PICTURE_CACHE:
                self.pictures.popitem(last=False)
        return picture

    def setup(self, agent: str):
        """``experiments.Setup`` of one agent label (loaded once)."""
        if agent not in self.agents:
            raise WorldagentError(f"no agent {agent!r} in this run; use one of: {', '.join(self.agents)}.")
        key = f"agent:{agent}"
        if key not in self._loaded:
            from worldagent import experiments

            self._loaded[key] = experiments.setup(self.env, self.agents[agent], self.generator()[0], options=None)
        return self._loaded[key]

    def warm_up(self, agents: Sequence[str] | None = None, episodes: int = EPISODE_BUCKETS[0], echo: Callable[[str], None] | None = None) -> None:
        """Compile G(z) and each of ``agents``' plays once (default: every agent, the run's first), what
        their first click would wait for. An agent that cannot load is skipped with one line to ``echo``."""
        if not self.run.has_generator(self.env):
            return
        self.warming = "G(z)"
        try:
            world = self.decode(np.zeros(self.latent_dim))
        finally:
            self.warming = None
        for agent in self.agents if agents is None else agents:
            if (agent, episode_bucket(episodes)) in self.ready:
                continue
            self.warming = agent
            try:
                self.play(world, agent, episodes, 0, 64)
            except Exception as error:  # noqa: BLE001  a broken agent must not stop the others' warm-up
                if echo:
                    echo(f"warming {self.env}: {agent} did not load ({' '.join(str(error).split())})")
            finally:
                self.warming = None

    def cold(self, agents: Sequence[str], episodes: int) -> dict:
        """Which of ``agents`` (known labels only) would compile before playing ``episodes`` episodes, and
        what the warm-up compiles now: what the page says while a first play waits."""
        bucket = episode_bucket(episodes)
        return {"cold": [a for a in agents if a in self.agents and (a, bucket) not in self.ready], "warming": self.warming}

    def play(self, world: Any, agent: str, episodes: int, seed: int, size: int, superseded: Callable[[], bool] = lambda: False) -> dict:
        """Play ``episodes`` episodes of ``agent`` on ``world`` now; where the agents went, as pixels on its picture, and the env's marks.

        ``superseded()`` is asked once this play holds the environment's lock: True (a newer play from the
        same page arrived meanwhile) drops it unplayed with ``Superseded``.
        """
        import jax

        bucket = episode_bucket(episodes)
        with self.lock:
            if superseded():
                raise Superseded
            setup = self.setup(agent)
            keys = jax.random.split(jax.random.key(int(seed)), int(episodes))
            padded = keys[np.minimum(np.arange(bucket), episodes - 1)]  # the same keys as before, the last repeated
            played, marks = replay_marked(self.spec, setup.env, setup.policy, world, padded, setup.params)
            self.ready.add((agent, bucket))
        played, marks = first_episodes(played, marks, int(episodes))
        return episodes_payload(self.spec, world, played, setup.params, size, marks)


def first_episodes(played, marks: dict, count: int):
    """The first ``count`` of replayed episodes and their marks (``replay_marked``'s outputs)."""
    from worldagent.evaluation.trajectories import Episodes

    if len(played) == count:
        return played, marks
    cut = Episodes(played.positions[:count], played.present[:count], played.steps[:count], {k: v[:count] for k, v in played.metrics.items()})
    return cut, {kind: (where[:count], shown[:count]) for kind, (where, shown) in marks.items()}


def stored_counts(run: Run, env: str) -> dict[str, int]:
    """{campaign: evaluations stored} of ``env``'s store, campaigns in store order (one query over the store's index)."""
    if not run.has_store(env):
        return {}
    with run.store(env) as store:
        rows = store.db.execute(
            "SELECT c.name, COUNT(e.id) FROM campaigns c LEFT JOIN evaluations e ON e.campaign_id = c.id GROUP BY c.id ORDER BY c.id"
        ).fetchall()
    return {name: int(count) for name, count in rows}


def run_latent_dim(run: Run, env: str, evaluations: list) -> int:
    """The latent size: the stored latents' (the commonest, if campaigns differ), else the generator's."""
    if evaluations:
        sizes = Counter(len(e.latent) for e in evaluations)
        return sizes.most_common(1)[0][0]
    if run.has_generator(env):
        return run.generator(env).latent_dim
    raise WorldagentError(f"{run.run_dir} has neither stored worlds nor a generator for {env}; run `worldagent reproduce --out {run.run_dir}`.")


def jax_row(batch: Any, row: int) -> Any:
    """Row ``row`` of a batched pytree, as numpy (unbatched)."""
    import jax

    return jax.tree_util.tree_map(lambda leaf: np.asarray(leaf[row]), batch)


def finite_or_none(value) -> float | None:
    value = float(value)
    return value if np.isfinite(value) else None


def rounded(values: np.ndarray, digits: int = 4) -> list:
    """Numbers for JSON: rounded, NaN as null."""
    array = np.round(np.asarray(values, np.float64), digits)
    return np.where(np.isfinite(array), array, None).tolist()


@dataclass
class Session:
    """The explorer's run: one ``EnvSession`` per environment (``Session.open``)."""

    run: Run
    envs: dict[str, EnvSession]

    @classmethod
    def open(cls, run_dir: Path | str) -> Session:
        return cls.of(Run.open(run_dir))

    @classmethod
    def of(cls, run: Run) -> Session:
        """The session of a run (``Run.open`` or ``Run.of_parts``)."""
        return cls(run, {env: EnvSession.open(run, env) for env in run.require_envs()})

    def env(self, name: str) -> EnvSession:
        if name not in self.envs:
            raise KeyError(name)
        return self.envs[name]

    def describe(self) -> dict:
        manifest = self.run.manifest
        return {
            "run_dir": str(self.run.run_dir),
            "preset": manifest.get("preset"),
            "seed": manifest.get("seed"),
            "envs": [env.describe() for env in self.envs.values()],
        }
