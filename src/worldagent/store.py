"""The run store: every world evaluated, with its latent, metrics and provenance (SQLite).

One file (``store.sqlite`` in a run directory) holds any number of campaigns. Each evaluation
is committed as soon as it finishes, so a killed campaign loses nothing it finished. The file
is opened in WAL mode: readers (a report, a notebook) never block the writer, and two campaigns
can write to one store. A file that is not a worldagent store, or of another schema version,
is refused with a one-line error.

Tables::

    meta(key, value)                       schema_version, created, worldagent version
    campaigns(id, name, env, objective, maximize, optimiser, budget, seed, config, created)
    evaluations(id, campaign_id, generation, slot, latent, world, score, episodes, started, finished)
    confirmations(id, agent, env, world, seed, repeats, episodes, arrays, started, finished)
    selections(id, name, world, campaign, generation, slot, metric, found, found_episodes, created)

``confirmations`` hold each selected world replayed on fresh episodes (``analysis.confirm``), one row
per (agent identity, env, world digest, confirmation seed, repeats); ``selections`` say which
selection picked which world from which evaluation, with the figure it was picked on (provenance).
Both are created on the first write, so stores from before them read as having none.

``latent`` is JSON (a list of floats), ``world`` the world's arrays as ``.npz`` bytes (no
pickle), ``episodes`` JSON: a list, one dict of metrics per episode.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import sqlite3
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from worldagent.errors import WorldagentError
from worldagent.files import can_create_files_in
from worldagent.identity import resumable_parts
from worldagent.sqlite_errors import one_line_sqlite_errors, sqlite_failure, sqlite_kind, use_wal

SCHEMA_VERSION = 1
STORE_FILE = "store.sqlite"
BUSY_SECONDS = 30.0  # how long a write waits for another process's before "database is locked" (a one-line error at the CLI)

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS campaigns (
    id INTEGER PRIMARY KEY, name TEXT UNIQUE NOT NULL, env TEXT NOT NULL, objective TEXT NOT NULL,
    maximize INTEGER NOT NULL, optimiser TEXT NOT NULL, budget INTEGER NOT NULL, seed INTEGER NOT NULL,
    config TEXT NOT NULL, created REAL NOT NULL);
CREATE TABLE IF NOT EXISTS evaluations (
    id INTEGER PRIMARY KEY, campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
    generation INTEGER NOT NULL, slot INTEGER NOT NULL, latent TEXT NOT NULL, world BLOB,
    score REAL, episodes TEXT NOT NULL, started REAL NOT NULL, finished REAL NOT NULL,
    UNIQUE (campaign_id, generation, slot));
"""

_CONFIRMATION_SCHEMA = """
CREATE TABLE IF NOT EXISTS confirmations (
    id INTEGER PRIMARY KEY, agent TEXT NOT NULL, env TEXT NOT NULL, world TEXT NOT NULL, seed INTEGER NOT NULL,
    repeats INTEGER NOT NULL, episodes TEXT NOT NULL, arrays BLOB, started REAL NOT NULL, finished REAL NOT NULL,
    UNIQUE (agent, env, world, seed, repeats));
CREATE TABLE IF NOT EXISTS selections (
    id INTEGER PRIMARY KEY, name TEXT NOT NULL, world TEXT NOT NULL, campaign TEXT NOT NULL, generation INTEGER NOT NULL,
    slot INTEGER NOT NULL, metric TEXT NOT NULL, found REAL, found_episodes INTEGER NOT NULL, created REAL NOT NULL,
    UNIQUE (name, world));
"""


@dataclass(frozen=True)
class Campaign:
    """A campaign's identity: what it optimises, how, and with which budget and seed."""

    id: int
    name: str
    env: str
    objective: str
    maximize: bool
    optimiser: str
    budget: int
    seed: int
    config: dict


@dataclass(frozen=True)
class Evaluation:
    """One evaluated world: ``score`` is the objective averaged over ``episodes``."""

    campaign: str
    generation: int
    slot: int
    latent: np.ndarray
    score: float
    episodes: list[dict]
    started: float
    finished: float
    world: dict[str, np.ndarray] | None = None


def encode_world(world: Any) -> bytes:
    """A world pytree (a flax dataclass of arrays) as ``.npz`` bytes."""
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **{name: np.asarray(value) for name, value in vars(world).items()})
    return buffer.getvalue()


def world_digest(arrays: dict[str, np.ndarray]) -> str:
    """sha256 of a world's arrays (names, dtypes, shapes, bytes): what "the same world" means after repair
    (DESIGN.md "Identity"); worlds that repair made identical share it."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        value = np.ascontiguousarray(arrays[name])
        digest.update(f"{name}:{value.dtype.str}:{value.shape}".encode())
        digest.update(value.tobytes())
    return digest.hexdigest()


@dataclass(frozen=True)
class Confirmation:
    """One world replayed on fresh episodes: ``episodes`` (one dict of metrics each) from ``repeats`` keys of ``seed``."""

    agent: str
    env: str
    world: str
    seed: int
    repeats: int
    episodes: list[dict]
    arrays: dict[str, np.ndarray] | None = None


@dataclass(frozen=True)
class Selected:
    """Provenance: selection ``name`` picked world ``world`` from evaluation (campaign, generation, slot) on ``found``
    (``metric`` averaged over ``found_episodes`` episodes)."""

    name: str
    world: str
    campaign: str
    generation: int
    slot: int
    metric: str
    found: float
    found_episodes: int


# numpy parses each array's header with ast.literal_eval, which CPython 3.11.7 cannot run in two threads at once
# ("SystemError: AST constructor recursion depth mismatch"): the explorer's server decodes a page's pictures in threads.
_DECODING = threading.Lock()


def decode_world(blob: bytes) -> dict[str, np.ndarray]:
    """The arrays of a world stored with ``encode_world`` (no pickle); one thread at a time (``_DECODING``)."""
    with _DECODING, np.load(io.BytesIO(blob), allow_pickle=False) as data:
        return {name: data[name] for name in data.files}


@one_line_sqlite_errors
class RunStore:
    """A SQLite run store (see the module docstring). Use as a context manager or ``close()``. Every SQLite failure
    (a locked store, a full disk, a read-only or damaged file) is a one-line ``WorldagentError`` naming the fix."""

    def __init__(self, path: Path | str, create: bool = True):
        path = Path(path)
        if path.suffix != ".sqlite":  # a run directory
            path = path / STORE_FILE
        if not path.exists() and not create:
            raise WorldagentError(f"no run store at {path}; run a campaign there first (`worldagent search ... --out {path.parent}`).")
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        try:
            self.db = sqlite3.connect(path, timeout=BUSY_SECONDS, isolation_level=None)
            self.db.execute(f"PRAGMA busy_timeout={int(BUSY_SECONDS * 1000)}")
            use_wal(self.db)
            if not self._tables():
                if not create:
                    raise WorldagentError(f"{path} is an empty file, not a run store; run a campaign there first.")
                self._create()
            self._check()
        except sqlite3.DatabaseError as error:
            kind = sqlite_kind(error)
            if kind in ("locked", "full", "io"):  # the machine, not the file: said as any store method says it
                raise sqlite_failure(error, path) from None
            if not (can_create_files_in(path.parent) and os.access(path, os.W_OK)):  # SQLite writes the store and its -wal, -shm beside it
                raise WorldagentError(
                    f"cannot open {path} ({error}): SQLite writes the store and files beside it in {path.parent}; make both writable or copy the run directory."
                ) from None
            raise WorldagentError(f"{path} is not a worldagent run store ({error}); point at a store.sqlite written by worldagent.") from None

    def _tables(self) -> set[str]:
        return {row[0] for row in self.db.execute("SELECT name FROM sqlite_master WHERE type='table'")}

    def _create(self) -> None:
        """Create the schema; safe when several processes create the same new store at once."""
        from worldagent import __version__

        self.db.execute("BEGIN IMMEDIATE")  # one creator at a time; the others find it done
        try:
            if not self._tables():
                for statement in filter(str.strip, _SCHEMA.split(";")):
                    self.db.execute(statement)
                self.db.executemany(
                    "INSERT OR IGNORE INTO meta VALUES (?, ?)",
                    [("schema_version", str(SCHEMA_VERSION)), ("created", str(time.time())), ("worldagent", __version__)],
                )
            self.db.execute("COMMIT")
        except BaseException:
            self.db.execute("ROLLBACK")
            raise

    def _check(self) -> None:
        tables = self._tables()
        if not {"meta", "campaigns", "evaluations"} <= tables:
            raise WorldagentError(f"{self.path} is a SQLite file but not a worldagent run store; use another path.")
        row = self.db.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()
        if row is None or int(row[0]) != SCHEMA_VERSION:
            found = row[0] if row else "none"
            fix = (
                "it was written by a newer worldagent: upgrade worldagent (pip install -U worldagent), or choose another --out"
                if row is not None and int(row[0]) > SCHEMA_VERSION
                else "choose another --out (or rerun with the worldagent that wrote it)"
            )
            raise WorldagentError(f"{self.path} has store schema version {found}; this worldagent reads version {SCHEMA_VERSION}: {fix}.")

    def check_intact(self) -> None:
        """Refuse, in one line, a store with damaged pages (SQLite's quick check), before a run resumes from it."""
        try:
            verdict = self.db.execute("PRAGMA quick_check(1)").fetchone()[0]
        except sqlite3.DatabaseError as error:
            verdict = str(error)
        if verdict != "ok":
            raise WorldagentError(f"{self.path} is damaged ({verdict.splitlines()[-1]}); restore it from a copy or choose another --out.")

    def close(self) -> None:
        self.db.close()

    def __enter__(self) -> RunStore:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- campaigns ------------------------------------------------------------------------------

    def campaign(self, name: str) -> Campaign | None:
        """The campaign called ``name``, or None."""
        row = self.db.execute("SELECT * FROM campaigns WHERE name=?", (name,)).fetchone()
        if row is None:
            return None
        id_, name, env, objective, maximize, optimiser, budget, seed, config, _ = row
        return Campaign(id_, name, env, objective, bool(maximize), optimiser, budget, seed, json.loads(config))

    def size(self) -> tuple[int, int]:
        """(campaigns, evaluations) the store holds, counted without reading them."""
        campaigns = self.db.execute("SELECT COUNT(*) FROM campaigns").fetchone()[0]
        return int(campaigns), int(self.db.execute("SELECT COUNT(*) FROM evaluations").fetchone()[0])

    def campaigns(self) -> list[Campaign]:
        return [self.campaign(row[0]) for row in self.db.execute("SELECT name FROM campaigns ORDER BY id")]

    def delete_campaigns(self, names: list[str] | tuple[str, ...]) -> int:
        """Delete campaigns ``names`` and their evaluations (a restarted phase starts clean); returns how many existed.

        Unknown names are ignored, so deleting is idempotent."""
        names = list(names)
        if not names:
            return 0
        marks = ",".join("?" * len(names))
        self.db.execute("BEGIN IMMEDIATE")  # both tables or neither (autocommit mode otherwise)
        try:
            found = self.db.execute(f"SELECT COUNT(*) FROM campaigns WHERE name IN ({marks})", names).fetchone()[0]
            self.db.execute(f"DELETE FROM evaluations WHERE campaign_id IN (SELECT id FROM campaigns WHERE name IN ({marks}))", names)
            self.db.execute(f"DELETE FROM campaigns WHERE name IN ({marks})", names)
            self.db.execute("COMMIT")
        except BaseException:
            self.db.execute("ROLLBACK")
            raise
        return int(found)

    def open_campaign(
        self, name: str, env: str, objective: str, maximize: bool, optimiser: str, budget: int, seed: int, config: dict, resume: bool
    ) -> Campaign:
        """Create campaign ``name``, or (``resume``) return it after checking it is the same campaign.

        Safe when several connections create the same campaign at once: one creates it, the
        others find it (and resume it, or are refused without ``resume``)."""
        existing = self.campaign(name)
        wanted = dict(env=env, objective=objective, maximize=bool(maximize), optimiser=optimiser, seed=int(seed), config=config)
        if existing is None:
            created = self.db.execute(  # one statement, atomic: a campaign another connection just made is left as it is
                "INSERT INTO campaigns (name, env, objective, maximize, optimiser, budget, seed, config, created) VALUES (?,?,?,?,?,?,?,?,?) "
                "ON CONFLICT(name) DO NOTHING",
                (name, env, objective, int(maximize), optimiser, int(budget), int(seed), json.dumps(config, sort_keys=True), time.time()),
            ).rowcount
            existing = self.campaign(name)
            if created:
                return existing
        if not resume:
            raise WorldagentError(f"campaign {name!r} already exists in {self.path}; pass --resume to continue it or choose another --name.")
        have = dict(
            env=existing.env,
            objective=existing.objective,
            maximize=existing.maximize,
            optimiser=existing.optimiser,
            seed=existing.seed,
            config=existing.config,
        )
        wanted = json.loads(json.dumps(wanted, sort_keys=True))
        have["config"], wanted["config"] = resumable_parts(have["config"], wanted["config"])
        if have != wanted:
            differing = sorted(k for k in have if have[k] != wanted[k])
            raise WorldagentError(f"campaign {name!r} was started with other settings ({', '.join(differing)}); resume it with the same ones.")
        if budget != existing.budget:
            with self.db:
                self.db.execute("UPDATE campaigns SET budget=? WHERE id=?", (int(budget), existing.id))
        return self.campaign(name)

    # -- evaluations ----------------------------------------------------------------------------

    def add(
        self, campaign: Campaign, generation: int, slot: int, latent, score: float, episodes: list[dict], started: float, world: Any = None
    ) -> None:
        """Commit one finished evaluation (atomic; a re-run of the same slot is refused)."""
        blob = encode_world(world) if world is not None else None
        value = float(score) if np.isfinite(score) else None  # SQLite has no NaN: NULL is "not a number"
        try:
            with self.db:
                self.db.execute(
                    "INSERT INTO evaluations (campaign_id, generation, slot, latent, world, score, episodes, started, finished) VALUES (?,?,?,?,?,?,?,?,?)",
                    (
                        campaign.id,
                        generation,
                        slot,
                        json.dumps([float(x) for x in np.ravel(latent)]),
                        blob,
                        value,
                        json.dumps(episodes, default=_json_number),
                        started,
                        time.time(),
                    ),
                )
        except sqlite3.IntegrityError:
            raise WorldagentError(
                f"campaign {campaign.name!r} already has generation {generation} slot {slot}; evaluations are never overwritten."
            ) from None

    def evaluations(self, campaign: str | None = None, with_worlds: bool = False) -> list[Evaluation]:
        """Evaluations in order (generation, slot), of one campaign or of all."""
        return list(self.iter_evaluations(campaign, with_worlds))

    def iter_evaluations(self, campaign: str | None = None, with_worlds: bool = False) -> Iterator[Evaluation]:
        query = (
            "SELECT c.name, e.generation, e.slot, e.latent, e.score, e.episodes, e.started, e.finished, "
            + ("e.world " if with_worlds else "NULL ")
            + "FROM evaluations e JOIN campaigns c ON c.id = e.campaign_id "
            + ("WHERE c.name=? " if campaign else "")
            + "ORDER BY c.id, e.generation, e.slot"
        )
        for name, generation, slot, latent, score, episodes, started, finished, world in self.db.execute(query, (campaign,) if campaign else ()):
            yield Evaluation(
                name,
                generation,
                slot,
                np.asarray(json.loads(latent)),
                float("nan") if score is None else score,
                json.loads(episodes),
                started,
                finished,
                decode_world(world) if world is not None else None,
            )

    def world(self, campaign: str, generation: int, slot: int) -> dict[str, np.ndarray]:
        """The stored world of one evaluation (without decoding the rest of its campaign's)."""
        row = self.db.execute(
            "SELECT e.world FROM evaluations e JOIN campaigns c ON c.id = e.campaign_id WHERE c.name=? AND e.generation=? AND e.slot=?",
            (campaign, int(generation), int(slot)),
        ).fetchone()
        if row is None or row[0] is None:
            raise WorldagentError(
                f"{self.path} holds no world for campaign {campaign!r} generation {generation} slot {slot}; pick a stored evaluation."
            )
        return decode_world(row[0])

    # -- confirmations (analysis.confirm) --------------------------------------------------------

    def _confirmation_tables(self) -> bool:
        return {"confirmations", "selections"} <= self._tables()

    def _ensure_confirmation_tables(self) -> None:
        if not self._confirmation_tables():
            with self.db:
                for statement in filter(str.strip, _CONFIRMATION_SCHEMA.split(";")):
                    self.db.execute(statement)

    def add_confirmation(self, confirmation: Confirmation, started: float) -> None:
        """Commit one world's confirmation (atomic); the same one committed twice is kept once."""
        self._ensure_confirmation_tables()
        c = confirmation
        blob = None
        if c.arrays is not None:
            buffer = io.BytesIO()
            np.savez_compressed(buffer, **{name: np.asarray(value) for name, value in c.arrays.items()})
            blob = buffer.getvalue()
        with self.db:
            self.db.execute(
                "INSERT OR IGNORE INTO confirmations (agent, env, world, seed, repeats, episodes, arrays, started, finished) VALUES (?,?,?,?,?,?,?,?,?)",
                (c.agent, c.env, c.world, int(c.seed), int(c.repeats), json.dumps(c.episodes, default=_json_number), blob, started, time.time()),
            )

    def confirmations(self, agent: str | None = None, env: str | None = None, with_worlds: bool = False) -> list[Confirmation]:
        """Stored confirmations (of one agent identity and env, or all), in the order they were made."""
        if not self._confirmation_tables():
            return []
        where, args = [], []
        for column, value in (("agent", agent), ("env", env)):
            if value is not None:
                where.append(f"{column}=?")
                args.append(value)
        query = f"SELECT agent, env, world, seed, repeats, episodes, {'arrays' if with_worlds else 'NULL'} FROM confirmations"
        query += (" WHERE " + " AND ".join(where) if where else "") + " ORDER BY id"
        return [
            Confirmation(a, e, w, s, r, json.loads(episodes), decode_world(blob) if blob is not None else None)
            for a, e, w, s, r, episodes, blob in self.db.execute(query, args)
        ]

    def add_selection(self, selected: Selected) -> None:
        """Record that a selection picked a world (kept once per selection and world)."""
        self._ensure_confirmation_tables()
        s = selected
        with self.db:
            self.db.execute(
                "INSERT OR IGNORE INTO selections (name, world, campaign, generation, slot, metric, found, found_episodes, created) "
                "VALUES (?,?,?,?,?,?,?,?,?)",
                (s.name, s.world, s.campaign, int(s.generation), int(s.slot), s.metric, _json_number(s.found), int(s.found_episodes), time.time()),
            )

    def selections(self, name: str | None = None) -> list[Selected]:
        """The worlds a selection picked (all selections' without ``name``), in the order they were recorded."""
        if not self._confirmation_tables():
            return []
        query = "SELECT name, world, campaign, generation, slot, metric, found, found_episodes FROM selections"
        rows = self.db.execute(query + (" WHERE name=? ORDER BY id" if name else " ORDER BY id"), (name,) if name else ())
        return [Selected(n, w, c, g, s, m, float("nan") if f is None else f, k) for n, w, c, g, s, m, f, k in rows]

    def export_csv(self, out: Path | str, campaign: str | None = None) -> Path:
        """One row per evaluation: campaign, generation, slot, score, mean of each metric, latent."""
        from worldagent.files import write_text

        rows = self.evaluations(campaign)
        metrics = sorted({key for row in rows for episode in row.episodes for key in episode})
        buffer = io.StringIO()
        writer = csv.writer(buffer)
        dim = max((len(row.latent) for row in rows), default=0)
        writer.writerow(["campaign", "generation", "slot", "score", *[f"mean_{m}" for m in metrics], "episodes", *[f"z{i}" for i in range(dim)]])
        for row in rows:
            means = [np.mean([float(e[m]) for e in row.episodes if m in e]) if row.episodes else "" for m in metrics]
            writer.writerow([row.campaign, row.generation, row.slot, row.score, *means, len(row.episodes), *row.latent.tolist()])
        return write_text(out, buffer.getvalue())


def _json_number(value):
    """JSON for numpy scalars; NaN and infinities become null (JSON has no NaN)."""
    number = float(np.asarray(value))
    return number if np.isfinite(number) else None
