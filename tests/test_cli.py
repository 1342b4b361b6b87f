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


def test_dataset_and_generator_commands_end_to_end(tmp_path):
    data = tmp_path / "harvest.npz"
    assert runner.invoke(app, ["dataset", "harvest", "--n", "40", "--out", str(data), "--quiet"]).exit_code == 0
    gen = tmp_path / "gen"
    args = ["generator", "train", "harvest", "--dataset", str(data), "--out", str(gen), "--epochs", "2", "--batch-size", "8", "--quiet"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert runner.invoke(app, ["generator", "show", str(gen), "--count", "2"]).exit_code == 0
    assert (gen / "traversals.png").exists() and (gen / "reconstructions.png").exists()
    report = runner.invoke(app, ["generator", "report", str(gen), "--samples", "50"])
    assert report.exit_code == 0 and '"validity_after_repair": 1.0' in report.output
    again = runner.invoke(app, args)  # finished run: resumes at its last epoch, trains nothing more
    assert again.exit_code == 0, again.output


def test_generator_commands_refuse_bad_input_in_one_line(tmp_path):
    cases = [
        (["dataset", "chess", "--out", str(tmp_path / "x.npz")], "unknown environment"),
        (["generator", "report", str(tmp_path / "none")], "holds no generator"),
        (["generator", "train", "racing", "--out", str(tmp_path / "g"), "--dataset", str(tmp_path / "missing.npz")], "does not exist"),
    ]
    for args, message in cases:
        result = runner.invoke(app, args)
        assert result.exit_code == 2 and message in result.output, result.output


def test_search_and_random_evaluation_commands(tmp_path, racing_vae, racing_data, racing_generator):
    from worldagent.store import RunStore
    from worldagent.worlds.generator import save_generator

    gen = save_generator(tmp_path / "gen", racing_vae, racing_data.save(tmp_path / "data.npz"), racing_generator)
    common = ["--agent", "driver", "--generator", str(gen), "--out", str(tmp_path / "run"), "--repeats", "2", "--quiet"]
    result = runner.invoke(app, ["evaluate", "random", "racing", "--worlds", "12", *common])
    assert result.exit_code == 0, result.output
    assert "normalised" in result.output and (tmp_path / "run" / "random-return-s0.png").exists()
    search = ["search", "racing", "--objective", "crashed", "--maximize", "--budget", "21", *common]
    result = runner.invoke(app, search)
    assert result.exit_code == 0, result.output
    again = runner.invoke(app, search)
    assert again.exit_code == 2 and "--resume" in again.output
    assert runner.invoke(app, [*search, "--resume"]).exit_code == 0
    with RunStore(tmp_path / "run", create=False) as store:
        assert [c.name for c in store.campaigns()] == ["random-return-s0", "cmaes-max-crashed-s0"]
        assert len(store.evaluations("cmaes-max-crashed-s0")) == 21
    bad = runner.invoke(app, ["search", "racing", "--objective", "speed", *common])
    assert bad.exit_code == 2 and "no metric 'speed'" in bad.output


def test_train_commands_write_an_agent_that_search_can_load(tmp_path):
    run = tmp_path / "ppo"
    result = runner.invoke(app, ["train", "racing", "--algo", "ppo", "--episodes", "40", "--out", str(run), "--quiet"])
    assert result.exit_code == 0, result.output
    assert (run / "curve.csv").exists() and (run / "curve.png").exists() and (run / "policy" / "policy.json").exists()
    result = runner.invoke(app, ["train", "harvest", "--episodes", "8", "--tagger", "0", "--out", str(tmp_path / "dqn"), "--quiet"])
    assert result.exit_code == 0, result.output
    from worldagent.commands.common import agent_policy as _agent

    assert _agent("racing", str(run), greedy=False).params is not None
    assert _agent("harvest", str(tmp_path / "dqn"), greedy=False).params is not None


def test_train_refuses_bad_requests_in_one_line(tmp_path):
    cases = [
        (["train", "racing", "--algo", "dqn"], "unknown algorithm 'dqn' for racing"),
        (["train", "racing", "--episodes", "0"], "at least one episode"),
        (["train", "harvest", "--worlds", "vae"], "--generator"),
        (["train", "racing", "--worlds", str(tmp_path / "missing.npz")], "does not exist"),
    ]
    for args, message in cases:
        result = runner.invoke(app, [*args, "--out", str(tmp_path / "x"), "--quiet"])
        assert result.exit_code == 2 and message in result.output, result.output
