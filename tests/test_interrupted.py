"""Ctrl-C in any command (issue 47 item 7): one line saying what the run directory kept and how to resume,
exit 130, from the CLI's one place that catches it (``commands.interrupted.InterruptedGroup``)."""

from __future__ import annotations

import numpy as np
from typer.testing import CliRunner

from worldagent.cli import app
from worldagent.commands.interrupted import given_option, interrupted_line, leaf_command
from worldagent.store import RunStore

runner = CliRunner()


def interrupt_diff_after_one_evaluation(monkeypatch):
    """``worldagent diff`` whose comparison commits one evaluation to its store, then meets Ctrl-C."""
    from worldagent import differential

    def interrupted(store, setup, **kwargs):
        campaign = store.open_campaign("diff-prior-s0", "racing", "return", False, "random", 8, 0, {}, resume=True)
        store.add(campaign, 0, 0, np.zeros(2), 0.0, [{"return": 1.0}], 0.0)
        raise KeyboardInterrupt

    monkeypatch.setattr(differential, "diff_setup", lambda *args, **kwargs: None)
    monkeypatch.setattr(differential, "diff", interrupted)


def test_ctrl_c_in_diff_says_what_its_store_kept_and_that_a_rerun_resumes(tmp_path, monkeypatch):
    interrupt_diff_after_one_evaluation(monkeypatch)
    out = tmp_path / "d"
    args = ["diff", "racing", "--agent", "scripted/driver", "--agent", "scripted/driver", "--worlds", "8", "--generator", str(tmp_path)]
    result = runner.invoke(app, [*args, "--out", str(out)])
    assert result.exit_code == 130
    (line,) = [line for line in result.output.splitlines() if line.strip()]
    assert line == (
        f"interrupted: {out} keeps what diff finished: store.sqlite (1 evaluation in 1 campaign); "
        "run the same command again to resume from there (finished work is not redone)."
    )
    with RunStore(out) as store:
        assert store.size() == (1, 1)


def test_the_line_names_the_default_out_nested_commands_and_resume_flags(tmp_path):
    from typer.main import get_group

    from worldagent.cli import app as typer_app

    group = get_group(typer_app)
    ctx = group.make_context("worldagent", ["envs"])
    command, path = leaf_command(group, ctx, ["generator", "train", "racing", "--quiet"])
    assert path == ["generator", "train"] and command.name == "train"
    search, _ = leaf_command(group, ctx, ["search", "racing"])
    words = ["search", "racing", f"--out={tmp_path / 'nothing'}"]
    assert given_option(words, "--out") == str(tmp_path / "nothing")
    line = interrupted_line(search, ["search"], words)
    assert line == f"interrupted before search kept anything in {tmp_path / 'nothing'}; run the same command again with --resume to start afresh."
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "manifest.json").write_text("{}")
    line = interrupted_line(search, ["search"], [*words[:2], "--out", str(tmp_path / "run"), "--resume"])
    assert "keeps what search finished: manifest.json; run the same command again to resume" in line
    envs, _ = leaf_command(group, ctx, ["envs"])
    assert interrupted_line(envs, ["envs"], ["envs"]) == "interrupted: envs keeps no run directory; run it again."
