"""``manifest.json``: what a ``reproduce`` run directory holds, and how far it got.

The manifest is the run directory's ledger. It records the preset and its whole config, the
seed, package versions, the device, and per phase (``"<env>/agent"``, ..., ``"report"``)::

    status    "running" | "done" | "failed"
    config    the preset's slice this phase depends on (``Preset.phase_config``)
    full_config, paper_config, depends
              every setting, the paper preset's, the phases it is computed from (the report's departures)
    started, finished, wall_s, outputs, error

It is rewritten atomically after every change of a phase, so a killed run leaves a manifest
saying which phase was running. Each environment's phases may run in a process of their own
(``pipeline.envs_at_once``), all writing this one file: every change takes the lock file
``.manifest.lock`` (``fcntl.flock``), reads the file again, applies only its own key's change and
writes the whole atomically, so no process loses another's phases; the next run skips the phases marked "done" and runs the
others again, each resuming from its own checkpoint or store. A "done" phase whose recorded
config differs from the preset's is refused (never silently reused): the fix is
``--restart PHASE`` or another run directory.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from worldagent.errors import WorldagentError
from worldagent.files import write_text
from worldagent.provenance import device, versions
from worldagent.runs import MANIFEST_FILE, parse_manifest, read_manifest
from worldagent.runs import MANIFEST_FORMAT as FORMAT_VERSION

try:
    import fcntl
except ImportError:  # Windows: no flock; the pipeline then runs its environments one after another
    fcntl = None


LOCK_FILE = ".manifest.lock"  # beside manifest.json; hidden, so listings of a run directory skip it


def can_share() -> bool:
    """Whether processes can share one manifest (the platform has ``fcntl.flock``)."""
    return fcntl is not None


@contextmanager
def manifest_lock(run_dir: Path) -> Iterator[None]:
    """Hold the run directory's manifest lock (exclusive, across processes) for one read-change-write."""
    if fcntl is None:
        yield
        return
    run_dir.mkdir(parents=True, exist_ok=True)
    with open(run_dir / LOCK_FILE, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


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
        """Write the manifest as it is in memory (atomically); changes go through ``_change``, which merges."""
        self.data["updated"] = time.time()
        return write_text(self.run_dir / MANIFEST_FILE, json.dumps(self.data, indent=1, default=_json_default))

    def _change(self, change: Callable[[dict], Any]) -> Any:
        """Apply ``change`` to the manifest as it is on disk now, under the lock, and write it: another
        process's phases, written since this one read the file, are kept. Returns what ``change`` returns."""
        with manifest_lock(self.run_dir):
            path = self.run_dir / MANIFEST_FILE
            if path.exists():
                self.data = parse_manifest(path)
            result = change(self.data)
            self.save()
        return result

    # -- the run ------------------------------------------------------------------------------

    def begin_run(self, preset_name: str, config: dict, envs: list[str]) -> None:
        """Record the preset, seeds, versions and device of this invocation."""
        about = dict(preset=preset_name, config=config, seed=config.get("seed"), versions=versions(), device=device())

        def change(data: dict) -> None:
            data.update(about)
            data["envs"] = list(dict.fromkeys([*data.get("envs", []), *envs]))  # earlier runs' first, in order
            data.setdefault("runs", []).append({"started": time.time(), "preset": preset_name, "envs": envs})

        self._change(change)

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
        entry = {"status": "running", "config": _normalise(config), **(about or {}), "started": time.time()}
        self._change(lambda data: data["phases"].__setitem__(key, entry))

    def annotate(self, key: str, about: dict | None) -> None:
        """Add ``about`` to a phase recorded before it was kept (its config matched, so it describes the phase)."""
        entry = self.data["phases"][key]
        if about and any(entry.get(name) != value for name, value in about.items()):
            self._change(lambda data: data["phases"][key].update(about))

    def finish(self, key: str, outputs: dict) -> dict:
        return self._change(lambda data: _ended(data["phases"][key], status="done", outputs=outputs, error=None))

    def fail(self, key: str, error: BaseException) -> dict:
        return self._change(lambda data: _ended(data["phases"][key], status="failed", error=f"{type(error).__name__}: {error}"))

    def forget(self, keys: list[str]) -> None:
        """Drop phases (``--restart``): they run again from scratch."""
        self._change(lambda data: [data["phases"].pop(key, None) for key in keys])


def _ended(entry: dict, **fields: Any) -> dict:
    """``entry`` of a phase that stopped (done or failed): ``fields``, when, and its wall time."""
    entry.update(finished=time.time(), **fields)
    entry["wall_s"] = round(entry["finished"] - entry["started"], 2)
    return entry


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
