"""The command line: help, the tracks sheet, and one-line errors for bad input."""

from __future__ import annotations

from PIL import Image
from typer.testing import CliRunner

from worldagent.cli import app

runner = CliRunner()


def test_help_lists_the_commands():
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    assert "tracks" in result.output


def test_tracks_draws_a_sheet(tmp_path):
    out = tmp_path / "sheet.png"
    result = runner.invoke(app, ["tracks", "--n", "3", "--seed", "5", "--out", str(out)])
    assert result.exit_code == 0, result.output
    with Image.open(out) as image:
        assert image.size[0] > 0


def test_negative_track_count_is_a_one_line_error(tmp_path):
    result = runner.invoke(app, ["tracks", "--n", "-2", "--out", str(tmp_path / "x.png")])
    assert result.exit_code == 2
    assert "error:" in result.output and len(result.output.strip().splitlines()) == 1
    assert not (tmp_path / "x.png").exists()


def test_drive_draws_an_episode_and_reports_its_metrics(tmp_path):
    out = tmp_path / "episode.png"
    result = runner.invoke(app, ["drive", "--seed", "3", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "lap True" in result.output and out.exists()


def test_drive_refuses_unknown_policies_and_formats(tmp_path):
    for args, message in ((["--policy", "psychic"], "unknown policy"), (["--out", str(tmp_path / "e.mp4")], ".gif or .png")):
        result = runner.invoke(app, ["drive", *args])
        assert result.exit_code == 2 and message in result.output
