"""The report's provenance section: preset, seed, versions, device, and every phase's status,
wall time and settings, folded under one summary line (it says how the result was made; it is
not the result). Settings are written as text, never as raw dicts.
"""

from __future__ import annotations

import json
from pathlib import Path

from worldagent.reports.page import esc, fmt, table


def overview(manifest: dict, run_dir: Path) -> str:
    """Preset, seeds, versions, device, and each phase's status, wall time and config (folded: provenance, not the result)."""
    rows = [
        ["preset", manifest.get("preset", "?")],
        ["seed", manifest.get("seed", "?")],
        ["environments", ", ".join(manifest.get("envs", []))],
        ["device", manifest.get("device", "?")],
        ["run directory", str(run_dir)],
    ]
    rows += [[f"version: {name}", version] for name, version in manifest.get("versions", {}).items()]
    entries = {key: entry for key, entry in manifest.get("phases", {}).items() if key != "report"}  # this report is being built
    phases = [
        [
            key,
            entry.get("status", "?"),
            fmt(entry.get("wall_s")),
            _time(entry.get("started")),
            _time(entry.get("finished")),
            settings_text(entry.get("config", {})),
            entry.get("error") or entry.get("outputs", {}).get("summary", ""),
        ]
        for key, entry in entries.items()
    ]
    total = sum(entry.get("wall_s") or 0.0 for entry in entries.values())
    return (
        f"<details><summary>Preset {esc(manifest.get('preset', '?'))}, seed {esc(manifest.get('seed', '?'))}, "
        f"{len(entries)} phases in {total:,.1f} s on {esc(manifest.get('device', '?'))}: versions, phases and their settings</summary>"
        + table(["", ""], rows)
        + "<h3>Phases</h3>"
        + table(["phase", "status", "wall s", "started", "finished", "config", "result"], phases)
        + f"<p>Total wall time of the phases: {total:,.1f} s.</p>"
        + "<h3>Preset</h3><pre>"
        + esc(json.dumps(preset_of_run(manifest.get("config", {}), manifest.get("envs", [])), indent=1))
        + "</pre></details>"
    )


def settings_text(config: dict, prefix: str = "") -> str:
    """A phase's settings as ``episodes 300, seeds 0 1`` (nested keys dotted), never a raw dict."""
    parts = []
    for key, value in sorted(config.items()):
        if isinstance(value, dict):
            parts.append(settings_text(value, f"{prefix}{key}."))
        elif isinstance(value, (list, tuple)):
            parts.append(f"{prefix}{key} " + (" ".join(fmt(v) for v in value) or "none"))
        else:
            parts.append(f"{prefix}{key} {fmt(value)}")
    return ", ".join(part for part in parts if part)


def preset_of_run(config: dict, envs: list[str]) -> dict:
    """The recorded preset with the budgets of only the environments the run ran (a preset holds every env's)."""
    if not isinstance(config.get("envs"), dict):
        return config
    return {**config, "envs": {name: budgets for name, budgets in config["envs"].items() if name in envs}}


def _time(stamp: float | None) -> str:
    import time

    return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(stamp)) if stamp else ""
