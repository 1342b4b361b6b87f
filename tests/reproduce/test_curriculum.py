"""``reproduce --curriculum``: the agent phase trains with a curriculum over G(z), records it as its
config, and the report's "Curriculum" section shows what it did (issue 25, item 3)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from typer.testing import CliRunner

from worldagent.cli import app
from worldagent.errors import WorldagentError
from worldagent.reproduce.manifest import Manifest
from worldagent.reproduce.pipeline import reproduce, restart_closure
from worldagent.reproduce.presets import PHASES, get_preset
from worldagent.runs import Run

TINY = get_preset("tiny")


def curriculum_section(page: str) -> str:
    return page.split('<section id="curriculum">')[1].split("</section>")[0]


def test_the_default_is_dr_and_its_config_is_unchanged():
    assert TINY.curriculum.name == "dr" and TINY.curriculum_of("racing") is None
    assert "curriculum" not in TINY.phase_config("racing", "agent")  # runs made before --curriculum still match
    assert json.loads(TINY.show())["curriculum"] == {"name": "dr", "target": None, "maximize": None, "settings": {}}


def test_a_curriculum_is_part_of_the_agent_phases_config():
    plr = TINY.with_curriculum("plr", settings={"buffer_size": 64})
    differ = [p for p in PHASES if plr.phase_config("racing", p) != TINY.phase_config("racing", p)]
    assert differ == ["agent"]
    assert plr.phase_config("racing", "agent")["curriculum"] == {"name": "plr", "settings": {"buffer_size": 64}}
    target = TINY.with_curriculum("target")  # without --target: each env's failure event
    assert target.curriculum_of("racing")["target"] == "crash_rate > 0.5" and target.curriculum_of("harvest")["target"] == "group_reward < 50"
    metric = TINY.with_curriculum("accel", "conflict", False)
    assert metric.curriculum_of("harvest") == {"name": "accel", "settings": {}, "target": "conflict", "maximize": False}
    assert "never replays" in metric.check_curriculum("harvest")  # the papers' 4,000 latents in a 4-episode budget: said
    assert TINY.with_curriculum("plr", settings={"buffer_size": 8}).check_curriculum("racing") is None  # 4 of 64 episodes
    assert TINY.check_curriculum("racing") is None  # dr
    # an adaptive curriculum draws G(z): redoing the generator redoes the agents (not so for dr)
    assert "agent" in restart_closure(["generator"], curriculum=True) and "agent" not in restart_closure(["generator"])


def test_a_default_runs_report_says_dr_and_how_to_ask_for_a_curriculum(racing_run):
    out, _ = racing_run
    section = curriculum_section((out / "report.html").read_text())
    assert "data-curriculum='dr'" in section and "<code>--curriculum plr</code>" in section and "<img" not in section
    manifest = Manifest.read(out).data
    assert "curriculum" not in manifest["phases"]["racing/agent"]["config"]
    assert manifest["phases"]["racing/agent"]["outputs"]["curriculum"] == "dr" and manifest["config"]["curriculum"]["name"] == "dr"
    assert Run.open(out).curriculum("racing")["snapshots"] == []


def test_changing_the_curriculum_of_a_finished_run_is_refused_with_the_fix(racing_copy):
    with pytest.raises(WorldagentError, match=r"phase racing/agent was run with another config \(curriculum None -> .*plr.*--restart agent"):
        reproduce(TINY.with_curriculum("plr"), racing_copy, ["racing"], progress=False, echo=lambda line: None)
    result = CliRunner().invoke(
        app, ["reproduce", "--preset", "tiny", "--env", "racing", "--curriculum", "plr", "--out", str(racing_copy), "--quiet"]
    )
    assert result.exit_code == 2 and "--restart agent" in result.output and len(result.output.strip().splitlines()) == 1


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--curriculum", "bogus"], "unknown curriculum 'bogus'; use one of"),
        (["--curriculum", "plr", "--curriculum-set", "replay_prob=2"], "replay_prob=2.0 is outside [0, 1]"),
        (["--curriculum", "plr", "--curriculum-set", "size=3"], "--curriculum-set 'size=3': write NAME=VALUE"),
        (["--curriculum-set", "buffer_size=64"], "curriculum dr takes no settings"),
        (["--curriculum", "plr", "--minimize"], "--maximize/--minimize direct a --target metric"),
        (["--curriculum", "accel", "--target", "laps > 1"], "laps"),
    ],
)
def test_a_bad_curriculum_is_refused_in_one_line_before_any_work(tmp_path, flags, message):
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["reproduce", "--preset", "tiny", "--env", "racing", "--out", str(out), "--quiet", *flags])
    assert result.exit_code == 2 and message in result.output, result.output
    assert len(result.output.strip().splitlines()) == 1 and "Traceback" not in result.output
    assert not out.exists()


def test_show_prints_the_curriculum():
    result = CliRunner().invoke(app, ["reproduce", "--preset", "tiny", "--env", "racing", "--curriculum", "target", "--show"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.output)["curriculum"] == {"name": "target", "target": None, "maximize": None, "settings": {}}


@pytest.mark.slow
def test_the_tiny_preset_with_plr_keeps_snapshots_and_reports_the_curriculum(tmp_path):
    from toy_env import registered

    out = tmp_path / "plr"
    with registered():
        preset = get_preset("tiny").with_curriculum("plr", settings={"buffer_size": 64})  # with the toy env's budgets
        manifest = reproduce(preset, out, ["toy"], progress=False, echo=lambda line: None).data
        page = (out / "report.html").read_text()
        with pytest.raises(
            WorldagentError, match=r"phase toy/agent was run with another config \(curriculum .* -> None\); rerun with --restart agent"
        ):
            reproduce(get_preset("tiny"), out, ["toy"], progress=False, echo=lambda line: None)  # back to dr: as any other change
    agent = manifest["phases"]["toy/agent"]
    assert agent["status"] == "done" and agent["config"]["curriculum"] == {"name": "plr", "settings": {"buffer_size": 64}}
    assert agent["outputs"]["curriculum"].startswith("plr buffer_size=64 ") and "with curriculum plr" in agent["outputs"]["summary"]
    run = json.loads((out / "toy" / "agent" / "run.json").read_text())
    assert run["distribution"] == f"toy/generator; curriculum {agent['outputs']['curriculum']}"  # G(z) of the run's generator
    snapshots = sorted((out / "toy" / "agent" / "curriculum").glob("buffer-*.npz"))
    assert snapshots and (out / "toy" / "figures" / "curriculum.png").is_file()
    section = curriculum_section(page)
    assert "data-curriculum='plr'" in section and agent["outputs"]["curriculum"] in section
    assert len(re.findall(r'<img [^>]*src="data:image/png;base64,', section)) == 1
    last = dict(np.load(snapshots[-1]))
    shown = [float(value) for value in re.findall(r'data-key="toy\.curriculum\.favoured\d\.score" data-value="([^"]+)"', section)]
    assert shown and np.allclose(shown, np.sort(last["score"])[::-1][: len(shown)])  # the buffer's best latents, best first
