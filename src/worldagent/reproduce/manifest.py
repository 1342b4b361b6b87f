"""``manifest.json``: what a ``reproduce`` run directory holds, and how far it got.

The manifest is the run directory's ledger. It records the preset and its whole config, the
seed, package versions, the device, and per phase (``"<env>/agent"``, ..., ``"report"``)::

    status    "running" | "done" | "failed"
    config    the preset's slice this phase depends on (``Preset.phase_config``)
    full_config, paper_config, depends
              every setting, the paper preset's, the phases it is computed from (the report's departures)
    started, finished, wall_s, outputs, error

It is rewritten atomically after every change of a phase, so a killed run leaves a manifest
saying which phase was running; the next run skips the phases marked "done" and runs the
others again, each resuming from its own checkpoint or store. A "done" phase whose recorded
config differs from the preset's is refused (never silently reused): the fix is
``--restart PHASE`` or another run directory.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from worldagent.errors import WorldagentError
from worldagent.files import write_text
from worldagent.provenance import device, versions
from worldagent.runs import MANIFEST_FILE, parse_manifest, read_manifest
from worldagent.runs import MANIFEST_FORMAT as FORMAT_VERSION


def phase_key(env: str | None, phase: str) -> str:
    """``"racing/agent"``, or ``"report"`` for a phase of the whole run."""
    return f"{env}/{phase}" if env else phase


def config_difference(have: dict, want: dict) -> str:
    """``"episodes 300 -> 500, seeds [0] -> [0, 1]"``: the fields that differ."""
    keys = sorted(set(have) | set(want))
    return ", ".join(f"{k} {have.get(k)!r} -> {want.get(k)!r}" for k in keys if have.get(k) != want.get(k))


class Manifest:
    """The manifest of one run directory (see the module docstring)."""

    def __init__(self, run_dir: Path | str, data: dict):
        self.run_dir = Path(run_dir)
        self.data = data

    @classmethod
    def open(cls, run_dir: Path | str) -> Manifest:
        """Read ``run_dir/manifest.json``, or start an empty one (not yet written)."""
        run_dir = Path(run_dir)
        path = run_dir / MANIFEST_FILE
        if not path.exists():
            return cls(run_dir, {"format_version": FORMAT_VERSION, "created": time.time(), "phases": {}})
        return cls(run_dir, parse_manifest(path))

    @classmethod
    def read(cls, run_dir: Path | str) -> Manifest:
        """The manifest of an existing run directory; refuses a directory without one (``runs.read_manifest``)."""
        return cls(Path(run_dir), read_manifest(run_dir))

    def save(self) -> Path:
        self.data["updated"] = time.time()
        return write_text(self.run_dir / MANIFEST_FILE, json.dumps(self.data, indent=1, default=_json_default))

    # -- the run ------------------------------------------------------------------------------

    def begin_run(self, preset_name: str, config: dict, envs: list[str]) -> None:
        """Record the preset, seeds, versions and device of this invocation."""
        self.data.update(preset=preset_name, config=config, seed=config.get("seed"), versions=versions(), device=device())
        self.data["envs"] = list(dict.fromkeys([*self.data.get("envs", []), *envs]))  # earlier runs' first, in order
        self.data.setdefault("runs", []).append({"started": time.time(), "preset": preset_name, "envs": envs})
        self.save()

    # -- phases -------------------------------------------------------------------------------

    def phase(self, key: str) -> dict | None:
        return self.data["phases"].get(key)

    def check_config(self, key: str, config: dict) -> None:
        """Refuse a phase recorded (finished or not) with another config: its outputs are not reusable."""
        entry = self.phase(key)
        have = (entry or {}).get("config")
        if have is not None and have != _normalise(config):
            raise WorldagentError(
                f"phase {key} was run with another config ({config_difference(have, _normalise(config))}); "
                f"rerun with --restart {key.split('/')[-1]} to redo it (and what depends on it), or use another --out."
            )

    def is_done(self, key: str, config: dict) -> bool:
        """Whether ``key`` finished with ``config`` (another recorded config is refused)."""
        self.check_config(key, config)
        entry = self.phase(key)
        return entry is not None and entry.get("status") == "done"

    def start(self, key: str, config: dict, about: dict | None = None) -> None:
        """Record ``key`` as running with ``config`` (what a resume compares) and ``about`` (what the report reads)."""
        self.data["phases"][key] = {"status": "running", "config": _normalise(config), **(about or {}), "started": time.time()}
        self.save()

    def annotate(self, key: str, about: dict | None) -> None:
        """Add ``about`` to a phase recorded before it was kept (its config matched, so it describes the phase)."""
        entry = self.data["phases"][key]
        if about and any(entry.get(name) != value for name, value in about.items()):
            entry.update(about)
            self.save()

    def finish(self, key: str, outputs: dict) -> dict:
        entry = self.data["phases"][key]
        entry.update(status="done", finished=time.time(), outputs=outputs, error=None)
        entry["wall_s"] = round(entry["finished"] - entry["started"], 2)
        self.save()
        return entry

    def fail(self, key: str, error: BaseException) -> dict:
        entry = self.data["phases"][key]
        entry.update(status="failed", finished=time.time(), error=f"{type(error).__name__}: {error}")
        entry["wall_s"] = round(entry["finished"] - entry["started"], 2)
        self.save()
        return entry

    def forget(self, keys: list[str]) -> None:
        """Drop phases (``--restart``): they run again from scratch."""
        for key in keys:
            self.data["phases"].pop(key, None)
        self.save()


def _normalise(config: dict) -> dict:
    """``config`` as it reads back from JSON (tuples become lists)."""
    return json.loads(json.dumps(config, default=_json_default))


def _json_default(value: Any):
    """JSON for numpy scalars and arrays, and paths."""
    import numpy as np

    if isinstance(value, Path):
        return str(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")
