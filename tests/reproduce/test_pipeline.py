"""The pipeline end to end on the tiny preset: phases, skipping, resuming, refusing changed configs."""

from __future__ import annotations

import json
import sqlite3

import pytest

from worldagent.errors import WorldagentError
from worldagent.reproduce import phases as phases_module
from worldagent.reproduce.manifest import Manifest
from worldagent.reproduce.phases import EnvContext
from worldagent.reproduce.pipeline import forget_phases, reproduce
from worldagent.reproduce.presets import PHASES, get_preset

TINY = get_preset("tiny")


def rows(store_path) -> dict[str, int]:
    """Evaluations per campaign of a store."""
    with sqlite3.connect(store_path) as db:
        return dict(db.execute("SELECT c.name, COUNT(e.id) FROM campaigns c LEFT JOIN evaluations e ON e.campaign_id = c.id GROUP BY c.name"))


def mtimes(root) -> dict[str, int]:
    """Modification times of every file under ``root`` but the report and the manifest."""
    return {
        str(p.relative_to(root)): p.stat().st_mtime_ns
        for p in sorted(root.rglob("*"))
        if p.is_file() and p.name not in ("report.html", "manifest.json") and "figures" not in p.parts and not p.name.endswith(("-wal", "-shm"))
    }


def test_every_phase_runs_and_is_recorded(racing_run):
    out, lines = racing_run
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["preset"] == "tiny" and manifest["config"] == TINY.to_dict() and manifest["seed"] == 0
    assert {"worldagent", "jax", "python"} <= set(manifest["versions"]) and manifest["device"]
    for phase in PHASES:
        entry = manifest["phases"][f"racing/{phase}"]
        assert entry["status"] == "done", (phase, entry.get("error"))
        assert entry["config"] == json.loads(json.dumps(TINY.phase_config("racing", phase)))
        assert entry["wall_s"] >= 0 and entry["finished"] >= entry["started"]
    assert manifest["phases"]["report"]["status"] == "done"
    for path in (
        "racing/dataset.npz",
        "racing/generator/vae.msgpack",
        "racing/generator/quality.json",
        "racing/agent/policy/policy.json",
        "racing/store.sqlite",
        "racing/influence/influence.json",
        "racing/figures/strategic.png",
        "report.html",
    ):
        assert (out / path).is_file(), path
    campaigns = rows(out / "racing" / "store.sqlite")
    assert campaigns["random-return-s0"] == TINY.budgets("racing").random_worlds
    assert campaigns["cmaes-min-return-s0"] >= TINY.budgets("racing").strategic_budget and "cmaes-max-return-s0" in campaigns
    assert {"compare-cmaes-min-return-s0", "compare-bo-min-return-s0", "compare-random-min-return-s0"} <= set(campaigns)
    assert sum(line.endswith("running") for line in lines) == len(PHASES) + 1  # one status line per phase, then its result


def test_a_rerun_skips_finished_phases_and_touches_nothing(racing_copy):
    before_rows, before_files = rows(racing_copy / "racing" / "store.sqlite"), mtimes(racing_copy)
    lines: list[str] = []
    reproduce(TINY, racing_copy, ["racing"], progress=False, echo=lines.append)
    assert rows(racing_copy / "racing" / "store.sqlite") == before_rows
    assert mtimes(racing_copy) == before_files
    assert [line.split(":")[0] for line in lines if "skipped" in line] == [f"racing/{p}" for p in PHASES]


def test_a_killed_run_resumes_where_it_stopped(racing_copy, monkeypatch):
    store = racing_copy / "racing" / "store.sqlite"
    finished = rows(store)
    with sqlite3.connect(store) as db:  # the strategic phase was killed half-way through its max search
        db.execute(
            "DELETE FROM evaluations WHERE id IN (SELECT e.id FROM evaluations e JOIN campaigns c ON c.id = e.campaign_id "
            "WHERE c.name = 'cmaes-max-return-s0' ORDER BY e.id DESC LIMIT 10)"
        )
    manifest = Manifest.open(racing_copy)
    manifest.start("racing/strategic", TINY.phase_config("racing", "strategic"))

    def killed(ctx):
        raise KeyboardInterrupt

    monkeypatch.setitem(phases_module.PHASE_FUNCTIONS, "strategic", killed)
    with pytest.raises(KeyboardInterrupt):
        reproduce(TINY, racing_copy, ["racing"], progress=False, echo=lambda line: None)
    entry = Manifest.open(racing_copy).phase("racing/strategic")
    assert entry["status"] == "failed" and "KeyboardInterrupt" in entry["error"]

    monkeypatch.undo()
    lines: list[str] = []
    reproduce(TINY, racing_copy, ["racing"], progress=False, echo=lines.append)
    assert rows(store) == finished  # the same evaluations as the uninterrupted run, nothing twice
    assert "racing/strategic: running" in lines and "racing/random: done already" in " ".join(lines)
    assert Manifest.open(racing_copy).phase("racing/strategic")["status"] == "done"


def test_a_changed_config_is_refused_with_the_fix(racing_copy):
    changed = TINY.with_budgets("racing", random_worlds=50)
    with pytest.raises(WorldagentError, match=r"phase racing/random was run with another config \(worlds 42 -> 50\); rerun with --restart random"):
        reproduce(changed, racing_copy, ["racing"], progress=False, echo=lambda line: None)
    with pytest.raises(WorldagentError, match="--restart agent"):
        reproduce(TINY.with_algo("acktr"), racing_copy, ["racing"], progress=False, echo=lambda line: None)


def test_restart_forgets_a_phase_and_what_depends_on_it(racing_copy):
    manifest = Manifest.open(racing_copy)
    forget_phases(manifest, EnvContext(racing_copy, "racing", TINY), ["strategic", "compare"])
    left = rows(racing_copy / "racing" / "store.sqlite")
    atlas = {"atlas-min-return-s0", "failure-mc-crash_rate>0.5-s0", "failure-is-crash_rate>0.5-s0"}
    assert set(left) == {"random-return-s0"} | atlas
    assert not (racing_copy / "racing" / "figures" / "strategic.png").exists()
    assert Manifest.open(racing_copy).phase("racing/strategic") is None
    assert Manifest.open(racing_copy).phase("racing/random")["status"] == "done"
    forget_phases(manifest, EnvContext(racing_copy, "racing", TINY), ["atlas"])  # the atlas and its estimates go together
    assert set(rows(racing_copy / "racing" / "store.sqlite")) == {"random-return-s0"}
    assert not (racing_copy / "racing" / "figures" / "atlas.png").exists()


def test_an_influence_that_finds_no_world_is_a_result_not_a_crash(racing_copy, monkeypatch):
    def nothing(ctx):
        raise WorldagentError("no world of 42 candidates has crash_rate > 0.5; raise --candidates or add a search budget.")

    Manifest.open(racing_copy).forget(["racing/influence"])
    monkeypatch.setitem(phases_module.PHASE_FUNCTIONS, "influence", nothing)
    reproduce(TINY, racing_copy, ["racing"], progress=False, echo=lambda line: None)
    entry = Manifest.open(racing_copy).phase("racing/influence")
    assert entry["status"] == "failed" and "no world of 42 candidates" in entry["error"]
    report = (racing_copy / "report.html").read_text()
    assert "no world of 42 candidates" in report
