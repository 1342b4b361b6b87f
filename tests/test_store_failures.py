"""Every SQLite failure of the run store is one line naming the fix (issue 47 item 7): a full disk, a read-only
store or folder, a damaged file, a store from a newer worldagent, a store another process holds."""

from __future__ import annotations

import os
import sqlite3

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from damaged_store import damage_evaluations, store_with_a_campaign
from worldagent.commands.console import friendly_errors
from worldagent.errors import WorldagentError
from worldagent.sqlite_errors import sqlite_kind
from worldagent.store import SCHEMA_VERSION, RunStore


class Cells:
    """A world as the store encodes it (its fields' arrays)."""

    def __init__(self, cells):
        self.cells = cells


def test_a_full_disk_while_adding_is_one_line_and_keeps_what_was_committed(tmp_path):
    store_with_a_campaign(tmp_path)
    with RunStore(tmp_path) as store:
        store.db.execute(f"PRAGMA max_page_count = {store.db.execute('PRAGMA page_count').fetchone()[0]}")  # the disk is full now
        campaign = store.campaign("c")
        with pytest.raises(WorldagentError, match=r"cannot be written: the disk is full; free some space .* run the same command again") as caught:
            store.add(campaign, 0, 1, np.zeros(2), 2.0, [{"return": 2.0}], 0.0, world=Cells(np.random.default_rng(0).random(20_000)))
    assert "\n" not in str(caught.value) and str(tmp_path / "store.sqlite") in str(caught.value)
    with RunStore(tmp_path) as store:
        assert [e.slot for e in store.evaluations("c")] == [0]  # nothing half-written


def test_writing_a_read_only_store_is_one_line_naming_both_places(tmp_path):
    store_with_a_campaign(tmp_path)
    with RunStore(tmp_path) as store:
        store.db.execute("PRAGMA query_only = ON")  # SQLite refuses writes as it does on a read-only file or mount
        with pytest.raises(WorldagentError, match=r"cannot be written \(attempt to write a readonly database\).* make both writable"):
            store.open_campaign("d", "racing", "return", False, "random", 4, 0, {}, resume=False)
        assert [c.name for c in store.campaigns()] == ["c"]  # reading still works


def test_a_store_in_a_read_only_folder_is_one_line(tmp_path):
    store_with_a_campaign(tmp_path / "run")
    (tmp_path / "run").chmod(0o555)
    try:
        if os.access(tmp_path / "run", os.W_OK) and os.geteuid() == 0:
            pytest.skip("permissions do not stop this user (root)")
        with pytest.raises(WorldagentError, match="make both writable"):
            RunStore(tmp_path / "run", create=False)
    finally:
        (tmp_path / "run").chmod(0o755)


def test_a_damaged_store_is_one_line_wherever_the_damage_is_read(tmp_path):
    damage_evaluations(store_with_a_campaign(tmp_path))
    with RunStore(tmp_path) as store:  # the schema pages are whole: the damage shows only when evaluations are read
        with pytest.raises(WorldagentError, match=r"is damaged \(.*malformed.*\); restore it from a copy or choose another --out") as caught:
            store.evaluations("c")
        with pytest.raises(WorldagentError, match="is damaged"):
            list(store.iter_evaluations("c"))  # a generator's failure too
    assert caught.value.__cause__ is None and "\n" not in str(caught.value)


def test_a_store_of_a_newer_schema_says_to_upgrade(tmp_path):
    path = store_with_a_campaign(tmp_path)
    with sqlite3.connect(path) as db:
        db.execute("UPDATE meta SET value=? WHERE key='schema_version'", (str(SCHEMA_VERSION + 1),))
    with pytest.raises(WorldagentError, match=r"written by a newer worldagent: upgrade worldagent \(pip install -U worldagent\)"):
        RunStore(tmp_path)


def test_a_locked_store_is_one_line_at_the_command_line(tmp_path, monkeypatch):
    path = store_with_a_campaign(tmp_path)
    monkeypatch.setattr("worldagent.store.BUSY_SECONDS", 0.2)
    command = typer.Typer()

    @command.command()
    @friendly_errors
    def write() -> None:
        with RunStore(path) as store:
            store.add(store.campaign("c"), 0, 1, np.zeros(2), 1.0, [], 0.0)

    other = sqlite3.connect(path, isolation_level=None)
    other.execute("BEGIN EXCLUSIVE")
    try:
        result = CliRunner().invoke(command, [])
    finally:
        other.execute("ROLLBACK")
        other.close()
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert "stayed locked by another process" in result.output and "another --out" in result.output


def test_a_bug_in_sql_keeps_its_traceback():
    assert sqlite_kind(sqlite3.OperationalError("no such table: nowhere")) == ""
    assert sqlite_kind(sqlite3.OperationalError("database or disk is full")) == "full"
    assert sqlite_kind(sqlite3.DatabaseError("file is not a database")) == "damaged"
