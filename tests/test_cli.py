"""The command line: help, the registry-driven commands, and one-line errors for bad input."""

from __future__ import annotations

import json

import pytest
from PIL import Image
from typer.testing import CliRunner

from worldagent.cli import app

runner = CliRunner()


def one_line_error(result, message: str) -> bool:
    """Exit code 2 and a single ``error:`` line holding ``message``."""
    lines = result.output.strip().splitlines()
    return result.exit_code == 2 and len(lines) == 1 and "error:" in lines[0] and message in result.output


def test_help_lists_the_commands_and_the_registered_envs():
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    for command in ("worlds", "play", "envs", "train", "search", "reproduce"):
        assert command in result.output
    train_help = runner.invoke(app, ["train", "--help"])
    assert "racing" in train_help.output and "harvest" in train_help.output


def test_envs_lists_every_registered_environment():
    result = runner.invoke(app, ["envs"])
    assert result.exit_code == 0, result.output
    text = result.output
    assert text.startswith("racing:") and "\nharvest:" in text
    assert "main: return" in text and "crash_rate = crashed" in text and "ppo (default), acktr" in text and "driver, random" in text
    assert "main: group_reward" in text and "dqn (default)" in text and "tagger" in text and "greedy" in text
    assert "optimiser:   cmaes" in text.split("\nharvest:")[0] and "optimiser:   bo" in text.split("\nharvest:")[1]


def test_worlds_draws_a_sheet_of_any_environment(tmp_path):
    for env in ("racing", "harvest"):
        out = tmp_path / f"{env}.png"
        result = runner.invoke(app, ["worlds", env, "--n", "3", "--seed", "5", "--out", str(out)])
        assert result.exit_code == 0, result.output
        with Image.open(out) as image:
            assert image.size[0] > 0


def test_worlds_refuses_bad_input_in_one_line(tmp_path):
    assert one_line_error(runner.invoke(app, ["worlds", "racing", "--n", "-2", "--out", str(tmp_path / "x.png")]), "at least one world")
    assert one_line_error(runner.invoke(app, ["worlds", "chess", "--out", str(tmp_path / "x.png")]), "unknown environment 'chess'")
    assert not (tmp_path / "x.png").exists()


def test_play_draws_episodes_and_reports_their_metrics(tmp_path):
    out = tmp_path / "episode.png"
    result = runner.invoke(app, ["play", "racing", "--policy", "driver", "--seed", "3", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "return " in result.output and "episodes crashed" in result.output and out.exists()


def test_play_refuses_unknown_policies_and_formats(tmp_path):
    result = runner.invoke(app, ["play", "racing", "--policy", "driver", "--out", str(tmp_path / "e.gif")])
    assert one_line_error(result, "use .png")
    result = runner.invoke(app, ["play", "racing", "--policy", "psychic", "--out", str(tmp_path / "e.png")])
    assert result.exit_code == 2 and "psychic" in result.output


def test_option_errors_are_one_line(tmp_path):
    common = ["--policy", "random", "--out", str(tmp_path / "e.png")]
    cases = [
        (["play", "racing", "--option", "tagger=0"], "racing has no option 'tagger'"),
        (["play", "harvest", "--option", "speed=3"], "harvest has no option 'speed'; its options: tagger"),
        (["play", "harvest", "--option", "tagger"], "write NAME=VALUE"),
        (["play", "harvest", "--option", "tagger=x"], "not a list of agent indices"),
        (["play", "harvest", "--option", "tagger=7"], "agents are numbered 0 to 3"),
    ]
    for args, message in cases:
        assert one_line_error(runner.invoke(app, [*args, *common]), message), (args, message)
    assert not (tmp_path / "e.png").exists()


@pytest.mark.integration
def test_dataset_and_generator_commands_end_to_end(tmp_path):
    data = tmp_path / "harvest.npz"
    assert runner.invoke(app, ["dataset", "harvest", "--n", "40", "--out", str(data), "--quiet"]).exit_code == 0
    gen = tmp_path / "gen"
    args = ["generator", "train", "harvest", "--dataset", str(data), "--out", str(gen), "--epochs", "2", "--batch-size", "8", "--quiet"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "active units" in result.output and "distinct decodes" in result.output  # what search will get, said after training
    assert "underfit:" in result.output  # 2 epochs on 36 maps: held-out maps decode worse than the mean map, and it says so
    assert runner.invoke(app, ["generator", "show", str(gen), "--count", "2"]).exit_code == 0
    assert (gen / "traversals.png").exists() and (gen / "reconstructions.png").exists()
    report = runner.invoke(app, ["generator", "report", str(gen), "--samples", "50"])
    assert report.exit_code == 0, report.output
    assert '"harvest"' in report.output and (gen / "quality.json").exists()
    quality = json.loads((gen / "quality.json").read_text())
    assert quality["warnings"] and all(f"warning: {line}" in report.output for line in quality["warnings"])
    assert {"latent", "sensitivity", "distinct_share"} <= set(quality["harvest"])
    assert "reused the VAE" not in result.output
    quality_history = json.loads((gen / "vae.json").read_text())["history"]
    again = runner.invoke(app, args + ["--repair", "apples=30"])  # finished run: trains nothing more, rebuilds the repair
    assert again.exit_code == 0, again.output
    assert f"reused the VAE already trained in {gen} (2 epochs); only the repair was rebuilt" in again.output.replace("\n", "")
    assert "apples=30" in again.output and "apples=30 (default)" not in again.output
    assert json.loads((gen / "vae.json").read_text())["history"] == quality_history
    # without --epochs, the VAE in --out is reused as trained (not resumed to the paper preset's 100 epochs)
    unset = [arg for arg in args if arg not in ("--epochs", "2")] + ["--repair", "apples=31"]
    third = runner.invoke(app, unset)
    assert third.exit_code == 0, third.output
    assert "reused the VAE already trained" in third.output.replace("\n", "")
    assert json.loads((gen / "vae.json").read_text())["history"] == quality_history


def test_generator_commands_refuse_bad_input_in_one_line(tmp_path):
    cases = [
        (["dataset", "chess", "--out", str(tmp_path / "x.npz")], "unknown environment"),
        (["generator", "report", str(tmp_path / "none")], "holds no generator"),
        (["generator", "train", "racing", "--out", str(tmp_path / "g"), "--dataset", str(tmp_path / "missing.npz")], "does not exist"),
        (
            ["generator", "train", "racing", "--out", str(tmp_path / "g"), "--repair", "apples"],
            "racing has no repair 'apples'; use one of: nearest, open",
        ),
        (["generator", "train", "racing", "--out", str(tmp_path / "g"), "--repair", "open", "--repair", "=3"], "write settings as NAME=VALUE"),
        (["generator", "train", "racing", "--out", str(tmp_path / "g"), "--free-bits", "-1"], "free_bits=-1.0"),
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


def _small_worlds(env, path):
    from worldagent.worlds.dataset import make_dataset

    return make_dataset(env, 16, 0, progress=False).save(path)


@pytest.mark.integration
def test_train_writes_an_agent_that_search_can_load(tmp_path):
    from worldagent.agents.loaders import load_agent
    from worldagent.envs import registry

    run = tmp_path / "ppo"
    worlds = _small_worlds("racing", tmp_path / "racing.npz")
    result = runner.invoke(app, ["train", "racing", "--episodes", "40", "--worlds", str(worlds), "--out", str(run), "--quiet"])
    assert result.exit_code == 0, result.output
    assert "trained ppo" in result.output  # racing's default algorithm
    assert (run / "curve.csv").exists() and (run / "curve.png").exists() and (run / "policy" / "policy.json").exists()
    assert load_agent(registry.get("racing"), str(run)).params is not None


@pytest.mark.slow  # the same command as above, with DQN (trained in tests/agents) and an env option
def test_train_harvest_with_a_tagger(tmp_path):
    from worldagent.agents.loaders import load_agent
    from worldagent.envs import registry

    worlds = _small_worlds("harvest", tmp_path / "harvest.npz")
    args = ["train", "harvest", "--episodes", "8", "--option", "tagger=0", "--worlds", str(worlds), "--out", str(tmp_path / "dqn"), "--quiet"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert load_agent(registry.get("harvest"), str(tmp_path / "dqn")).params is not None


def test_train_refuses_bad_requests_in_one_line(tmp_path):
    cases = [
        (["train", "racing", "--algo", "dqn"], "unknown algorithm 'dqn' for racing"),
        (["train", "racing", "--episodes", "0"], "--episodes is 0; it must be at least 1"),
        (["train", "harvest", "--worlds", "vae"], "--generator"),
        (["train", "racing", "--option", "tagger=0"], "racing has no option 'tagger'"),
        (["train", "racing", "--worlds", str(tmp_path / "missing.npz")], "does not exist"),
    ]
    for args, message in cases:
        result = runner.invoke(app, [*args, "--out", str(tmp_path / "x"), "--quiet"])
        assert result.exit_code == 2 and message in result.output, result.output


def test_progress_bars_draw_on_stderr_so_stdout_stays_a_commands_output(capfd):
    from worldagent.progress import progress_bar

    with progress_bar("decoding", 3) as advance:
        for _ in range(3):
            advance()
    print('{"json": 1}')
    out, err = capfd.readouterr()
    assert out == '{"json": 1}\n' and "decoding" in err
