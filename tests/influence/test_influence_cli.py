"""``worldagent influence``: one-line errors for bad input, and a whole run on a tiny budget."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from worldagent.cli import app

runner = CliRunner()


@pytest.mark.parametrize(
    ("select", "message"),
    [
        ("crashed =>1", "bad operator '=>'"),
        ("__import__('os').system('true')", "unexpected '('"),
        ("speed > 1", "unknown racing metric 'speed'"),
        ("crashed >", "missing number"),
        ("", "the selection is empty"),
    ],
)
def test_a_bad_select_exits_2_with_one_line(tmp_path, select, message):
    # the generator does not exist: the selection must be refused before anything is loaded
    result = runner.invoke(
        app, ["influence", "racing", "--agent", "driver", "--generator", str(tmp_path / "none"), "--select", select, "--out", str(tmp_path / "run")]
    )
    assert result.exit_code == 2, result.output
    assert "error:" in result.output and message in result.output
    assert len(result.output.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()


def test_other_bad_options_exit_2(tmp_path):
    common = ["--agent", "driver", "--generator", str(tmp_path), "--out", str(tmp_path / "run")]
    for args, message in (
        (["influence", "boats", "--select", "reward > 0", *common], "unknown environment 'boats'"),
        (["influence", "racing", "--select", "reward > 0", "--algo", "dqn", *common], "unknown algorithm 'dqn' for racing"),
        (["influence", "racing", "--select", "reward > 0", "--option", "tagger=0", *common], "racing has no option 'tagger'"),
        (["influence", "harvest", "--select", "crash_rate > 0.5", *common], "unknown harvest metric 'crash_rate'"),
        (["influence", "racing", "--select", "reward > 0", "--rounds", "0", *common], "--rounds is 0; pass 1"),
        (["influence", "racing", "--select", "reward > 0", "--runs-per-program", "0", *common], "--runs-per-program is 0; pass at least 1"),
    ):
        result = runner.invoke(app, args)
        assert result.exit_code == 2 and message in result.output, result.output


@pytest.mark.slow  # the experiment itself runs in test_experiment.py; this is its CLI wrapper end to end
def test_a_whole_racing_run_prints_the_table_and_writes_figure_and_json(tmp_path, racing_vae, racing_data, racing_generator):
    from worldagent.worlds.generator import save_generator

    gen = save_generator(tmp_path / "gen", racing_vae, racing_data.save(tmp_path / "data.npz"), racing_generator)
    out = tmp_path / "run"
    args = [
        "influence",
        "racing",
        "--agent",
        "driver",
        "--generator",
        str(gen),
        "--select",
        "progress >= 0",
        "--algo",
        "ppo",
        "--episodes",
        "4",
        "--seeds",
        "1",
        "--candidates",
        "8",
        "--eval-worlds",
        "4",
        "--repeats",
        "1",
        "--confirm",
        "0",  # the CLI wrapper's table and files; confirmed selection has tests of its own (test_confirmed_selection.py)
        "--out",
        str(out),
        "--quiet",
    ]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "crash rate" in result.output and "± n/a" in result.output  # one seed: no interval
    assert "8 of 8 worlds have progress >= 0" in result.output
    assert (out / "influence.png").is_file()
    assert json.loads((out / "influence.json").read_text())["config"]["seeds"] == [0]
