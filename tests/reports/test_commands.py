"""``worldagent strategic`` and ``worldagent compare`` on tiny budgets, and their one-line errors."""

from __future__ import annotations

import pytest
from PIL import Image
from typer.testing import CliRunner

from worldagent.cli import app
from worldagent.store import RunStore

runner = CliRunner()


@pytest.fixture(scope="module")
def generator_dir(tmp_path_factory, racing_vae, racing_data, racing_generator):
    from worldagent.worlds.generator import save_generator

    root = tmp_path_factory.mktemp("gen")
    return save_generator(root / "gen", racing_vae, racing_data.save(root / "data.npz"), racing_generator)


def test_strategic_reuses_the_random_evaluation_and_draws_the_figure(tmp_path, generator_dir):
    common = ["--agent", "driver", "--generator", str(generator_dir), "--out", str(tmp_path), "--repeats", "2", "--quiet"]
    assert runner.invoke(app, ["evaluate", "random", "racing", "--worlds", "12", *common]).exit_code == 0
    with RunStore(tmp_path, create=False) as store:
        random_done = [e.finished for e in store.evaluations("random-return-s0")]
    result = runner.invoke(app, ["strategic", "racing", "--budget", "5", "--random-worlds", "12", *common])
    assert result.exit_code == 0, result.output
    assert "min " in result.output and "episodes crashed" in result.output and "random mean" in result.output
    with Image.open(tmp_path / "strategic-return-s0.png") as image:
        assert image.format == "PNG" and image.size[0] > 1000
    with RunStore(tmp_path, create=False) as store:
        assert [e.finished for e in store.evaluations("random-return-s0")] == random_done  # reused, not rerun
        assert len(store.evaluations("cmaes-min-return-s0")) == 21  # one CMA-ES generation
        total = len(store.evaluations())
    again = runner.invoke(app, ["strategic", "racing", "--budget", "5", "--random-worlds", "12", *common])
    assert again.exit_code == 0, again.output
    with RunStore(tmp_path, create=False) as store:
        assert len(store.evaluations()) == total


def test_compare_writes_the_figure_table_and_csv(tmp_path, generator_dir):
    args = [
        "compare",
        "racing",
        "--agent",
        "driver",
        "--generator",
        str(generator_dir),
        "--out",
        str(tmp_path),
        "--budget",
        "6",
        "--seeds",
        "2",
        "--optimisers",
        "cmaes,random",
        "--random-worlds",
        "20",
        "--repeats",
        "2",
        "--quiet",
    ]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "| cmaes | 2 | 6 |" in result.output and "| random | 2 | 6 |" in result.output
    assert (tmp_path / "comparison.png").stat().st_size > 10_000
    assert (tmp_path / "comparison.md").read_text().startswith("| optimiser |")
    assert (tmp_path / "comparison.csv").read_text().splitlines()[0].startswith("optimiser,seeds,evaluations")
    with RunStore(tmp_path, create=False) as store:
        names = {c.name for c in store.campaigns()}
    assert names == {"random-return-s1000", *(f"compare-{o}-min-return-s{s}" for o in ("cmaes", "random") for s in (0, 1))}


@pytest.mark.parametrize(
    "args, message",
    [
        (["compare", "racing", "--optimisers", "cmaes,sgd"], "--optimisers 'cmaes,sgd'"),
        (["compare", "racing", "--seeds", "0"], "--seeds is 0"),
        (["compare", "racing", "--random-seed", "1"], "--random-seed 1 is one of the optimisers' seeds"),
        (["strategic", "racing", "--budget", "0"], "--budget is 0"),
        (["strategic", "racing", "--metric", "speed"], "no metric 'speed'"),
        (["strategic", "chess"], "unknown environment 'chess'"),
    ],
)
def test_bad_input_is_a_one_line_error(tmp_path, generator_dir, args, message):
    result = runner.invoke(app, [*args, "--agent", "driver", "--generator", str(generator_dir), "--out", str(tmp_path), "--quiet"])
    assert result.exit_code == 2, result.output
    assert message in result.output and len(result.output.strip().splitlines()) == 1, result.output


def test_a_missing_generator_names_the_fix(tmp_path):
    result = runner.invoke(
        app, ["strategic", "racing", "--agent", "driver", "--generator", str(tmp_path / "none"), "--out", str(tmp_path), "--quiet"]
    )
    assert result.exit_code == 2 and "worldagent generator train" in result.output
