"""Stores for the failure tests: one with a campaign, and damage to its evaluations table."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np

from worldagent.store import RunStore


def store_with_a_campaign(folder: Path) -> Path:
    """A run store in ``folder`` holding campaign "c" with one evaluation; its file's path."""
    with RunStore(folder) as store:
        campaign = store.open_campaign("c", "racing", "return", False, "random", 4, 0, {}, resume=False)
        store.add(campaign, 0, 0, np.zeros(2), 1.0, [{"return": 1.0}], 0.0)
    return folder / "store.sqlite"


def damage_evaluations(path: Path) -> Path:
    """Overwrite the root page of the evaluations table of the store file at ``path`` with junk: the schema
    pages stay whole, so the damage shows only when evaluations are read."""
    db = sqlite3.connect(path)
    page_size = db.execute("PRAGMA page_size").fetchone()[0]
    root = db.execute("SELECT rootpage FROM sqlite_master WHERE name = 'evaluations'").fetchone()[0]
    db.close()
    with open(path, "r+b") as handle:
        handle.seek((root - 1) * page_size)
        handle.write(b"\x07" * page_size)
    return path
