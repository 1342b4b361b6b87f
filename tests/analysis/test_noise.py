"""The world's share of an episode's outcome (analysis.noise): ICC(1) on simulated worlds with a known share, its
interval's coverage, reliability as Spearman–Brown, the edge cases, failing episodes on failing worlds, and
``worldagent evaluate random`` printing the share and writing it to its JSON."""

from __future__ import annotations

import dataclasses
import json

import jax
import numpy as np
import pytest
from typer.testing import CliRunner

from worldagent.analysis.noise import (
    episode_failures,
    episode_values,
    failing_on_failing_worlds,
    noise_summary,
    repeats_for,
    share_line,
    spearman_brown,
    world_share,
)
from worldagent.events import parse_selection
from worldagent.store import Evaluation, RunStore


def simulated(rng, icc: float, worlds: int, repeats: int) -> np.ndarray:
    """values[worlds, repeats] = world effect + dice, with the world's share of one episode's variance ``icc``."""
    effects = rng.normal(0.0, np.sqrt(icc), (worlds, 1))
    return 3.0 + effects + rng.normal(0.0, np.sqrt(1 - icc), (worlds, repeats))


def evaluation(episodes: list[dict]) -> Evaluation:
    return Evaluation("c", 0, 0, np.zeros(2), float("nan"), episodes, 0.0, 0.0)


@pytest.mark.parametrize("icc", [0.1, 0.4, 0.8])
def test_the_share_of_simulated_worlds_is_recovered_within_its_interval(icc):
    share = world_share(simulated(np.random.default_rng(0), icc, 600, 8))
    assert share.low <= icc <= share.high and share.low < share.icc < share.high
    assert abs(share.icc - icc) < 0.06 and share.worlds == 600 and share.repeats == 8


def test_the_interval_covers_the_true_share_in_most_simulations():
    rng = np.random.default_rng(7)
    shares = [world_share(simulated(rng, 0.2, 120, 6)) for _ in range(100)]
    covered = np.mean([s.low <= 0.2 <= s.high for s in shares])
    assert 0.88 <= covered <= 1.0  # a 95% interval: ~95 of 100
    assert abs(np.mean([s.icc for s in shares]) - 0.2) < 0.02  # and the estimate is not biased


def test_reliability_is_spearman_brown_and_the_correlation_of_two_independent_scores():
    values = simulated(np.random.default_rng(3), 0.15, 4000, 16)
    share = world_share(values[:, :8])
    assert share.reliability == pytest.approx(spearman_brown(share.icc, 8))
    assert share.reliability_low == pytest.approx(spearman_brown(share.low, 8))
    halves = np.corrcoef(values[:, :8].mean(axis=1), values[:, 8:].mean(axis=1))[0, 1]  # two fresh 8-episode scores of each world
    assert halves == pytest.approx(share.reliability, abs=0.03)
    assert spearman_brown(0.15, 8) == pytest.approx(8 * 0.15 / (1 + 7 * 0.15))


def test_repeats_for_is_the_fewest_episodes_that_reach_the_reliability():
    for icc, reliability in ((0.097, 0.8), (0.35, 0.9), (0.6, 0.85)):
        more = repeats_for(icc, reliability)
        assert spearman_brown(icc, more) >= reliability > spearman_brown(icc, more - 1)
    assert repeats_for(0.097) == 38  # racing's quick run in issue 50: 8 episodes give 0.46
    assert repeats_for(0.0) is None and repeats_for(float("nan")) is None and repeats_for(1.0) == 1


def test_edge_cases_no_dice_no_variance_one_world_and_missing_values():
    constant_per_world = np.repeat(np.arange(5.0)[:, None], 4, axis=1)
    share = world_share(constant_per_world)
    assert share.icc == share.low == share.high == share.reliability == 1.0  # no dice: the world is everything
    assert np.isnan(world_share(np.ones((5, 4))).icc)  # no variance at all: nothing to share
    one = world_share(np.array([[1.0, 2.0, 3.0]]))
    assert np.isnan(one.icc) and one.worlds == 1
    dice_only = world_share(np.tile([0.0, 1.0], (6, 2)))  # every world the same mean: the world explains nothing
    assert dice_only.icc == 0.0 and dice_only.reliability == 0.0 and dice_only.high < 0.5  # truncated at 0
    with_nan = np.vstack([simulated(np.random.default_rng(0), 0.5, 30, 4), [[np.nan, 1, 2, 3]]])
    assert world_share(with_nan).worlds == 30  # a world with a missing episode is left out
    assert world_share(np.ones((5, 4))).as_dict()["icc"] is None  # NaN as null in JSON
    with pytest.raises(ValueError, match="repeats >= 2"):
        world_share(np.ones((5, 1)))


def test_failing_on_failing_worlds_by_hand():
    fails = np.array([[1, 1, 0, 0], [1, 0, 0, 0], [0, 0, 0, 0], [1, 1, 1, 1]], bool)
    assert failing_on_failing_worlds(fails) == pytest.approx(6 / 7)  # worlds 0 (half) and 3 hold 6 of the 7 failing episodes
    assert failing_on_failing_worlds(np.eye(4, dtype=bool)) == 0.0  # every failure alone on its world: dice
    assert np.isnan(failing_on_failing_worlds(np.zeros((3, 4), bool)))


def test_noise_summary_of_stored_episodes_and_its_line():
    rng = np.random.default_rng(2)
    returns = simulated(rng, 0.1, 200, 8)
    evaluations = [evaluation([{"return": float(r), "crashed": float(r < 2.5)} for r in row]) for row in returns]
    failure = parse_selection("crashed > 0.5", "racing")
    np.testing.assert_array_equal(episode_values(evaluations, "return"), returns)
    np.testing.assert_array_equal(episode_failures(evaluations, failure), returns < 2.5)
    summary = noise_summary(evaluations, ["return"], failure)
    assert summary["worlds"] == 200 and summary["repeats"] == 8
    assert summary["metrics"]["return"]["icc"] == pytest.approx(world_share(returns).icc)
    assert summary["failure"]["episodes_failing"] == pytest.approx((returns < 2.5).mean())
    assert summary["failure"]["on_failing_worlds"] == pytest.approx(failing_on_failing_worlds(returns < 2.5))
    line = share_line(summary, "return")
    assert line.startswith(f"world's share of return {summary['metrics']['return']['icc']:.2f} [") and "reliability at 8 episodes" in line
    assert "mostly dice" in line and "failing episodes on worlds failing >= half" in line
    assert noise_summary(evaluations[:1], ["return"]) == {}  # one world
    assert noise_summary([evaluation([{"return": 1.0}])] * 5, ["return"]) == {}  # one episode per world
    assert noise_summary([evaluation([{"return": 1.0}] * 2), evaluation([{"return": 1.0}] * 3)], ["return"]) == {}  # uneven


# -- the CLI: `worldagent evaluate random` on the toy --------------------------------------------


@pytest.fixture(scope="module")
def toy_with_failure():
    """The toy with a failure event (it has none of its own), registered for this module."""
    import toy_env
    from worldagent.envs import registry

    spec = registry.register(dataclasses.replace(toy_env.SPEC, failure="reached < 0.5"))
    try:
        yield spec
    finally:
        registry.unregister(spec.name)


@pytest.fixture(scope="module")
def toy_generator(toy_with_failure, tmp_path_factory):
    """A toy G(z) from an untrained VAE (random weights of the right shapes: its repair still makes every world valid)."""
    from worldagent.worlds.dataset import make_dataset
    from worldagent.worlds.generator import build_generator, save_generator
    from worldagent.worlds.vae import TrainedVAE, VAEConfig, make_vae

    spec, folder = toy_with_failure, tmp_path_factory.mktemp("toy-gen")
    dataset = make_dataset(spec.name, 32, 0, progress=False)
    data_path = dataset.save(folder / "data.npz")
    config = VAEConfig(encoder=(16,), decoder=(16,), latent_dim=3)
    model = make_vae(spec.cell_count, config)
    shapes = jax.eval_shape(model.init, jax.random.key(0), np.zeros((1, spec.cell_count), np.float32), jax.random.key(1))["params"]
    weights = np.random.default_rng(1)
    params = jax.tree_util.tree_map(lambda leaf: weights.normal(0.0, 0.5, leaf.shape).astype(leaf.dtype), shapes)
    vae = TrainedVAE(model, params, config, spec.name, spec.cell_shape, dataset.fingerprint, [], np.zeros(0, np.int64))
    return save_generator(folder / "generator", vae, data_path, build_generator(vae, dataset))


def test_evaluate_random_prints_the_worlds_share_and_writes_it_to_its_json(toy_with_failure, toy_generator, tmp_path):
    from worldagent.cli import app
    from worldagent.commands.evaluate import evaluation_record

    out = tmp_path / "run"
    arguments = ["evaluate", "random", "toy", "--agent", "random", "--generator", str(toy_generator), "--worlds", "24", "--repeats", "4"]
    result = CliRunner().invoke(app, [*arguments, "--out", str(out), "--quiet"])
    assert result.exit_code == 0, result.output
    with RunStore(out, create=False) as store:
        evaluations = store.evaluations("random-return-s0")
    returns = episode_values(evaluations, "return")
    reached = episode_values(evaluations, "reached") < 0.5
    expected = world_share(returns)
    record = json.loads((out / "random-return-s0.json").read_text())
    assert record["campaign"] == "random-return-s0" and record["worlds"] == 24 and record["repeats"] == 4 and record["metric"] == "return"
    assert record["mean"] == pytest.approx(np.mean(returns)) and record["sd"] == pytest.approx(np.std(returns.mean(axis=1)))
    assert np.isfinite(expected.icc)  # the random walker reaches some goals: the returns vary
    assert record["metrics"]["return"]["icc"] == pytest.approx(expected.icc)
    assert record["metrics"]["return"]["reliability"] == pytest.approx(expected.reliability)
    assert record["failure"]["event"] == "reached < 0.5"
    assert record["failure"]["share"]["icc"] == pytest.approx(world_share(reached.astype(float)).icc, nan_ok=True)
    assert record["failure"]["episodes_failing"] == pytest.approx(reached.mean())
    assert f"world's share of return {expected.icc:.2f} [{expected.low:.2f}, {expected.high:.2f}]" in result.output
    assert "reliability at 4 episodes" in result.output and "of the failure (reached < 0.5)" in result.output
    one = evaluation_record(toy_with_failure, [evaluation([{"return": 1.0, "reached": 0.0}])] * 3, "return", "c")
    assert one["worlds"] == 3 and one["repeats"] == 1 and "metrics" not in one  # one episode a world: no share to say


def test_evaluate_worlds_says_the_share_of_the_given_worlds(toy_with_failure, tmp_path):
    from worldagent.cli import app
    from worldagent.worlds.dataset import make_dataset

    data = make_dataset(toy_with_failure.name, 16, 200, progress=False).save(tmp_path / "given.npz")
    out = tmp_path / "run"
    arguments = ["evaluate", "worlds", "toy", "--agent", "random", "--worlds", str(data), "--repeats", "3", "--out", str(out), "--quiet"]
    result = CliRunner().invoke(app, arguments)
    assert result.exit_code == 0, result.output
    (path,) = out.glob("worlds-given-*.json")
    record = json.loads(path.read_text())
    with RunStore(out, create=False) as store:
        expected = world_share(episode_values(store.evaluations(record["campaign"]), "return"))
    assert record["worlds"] == 16 and record["repeats"] == 3 and record["failure"]["event"] == "reached < 0.5"
    assert record["metrics"]["return"]["icc"] == pytest.approx(expected.icc, nan_ok=True)
    assert "world's share of return" in result.output and f"-> {path}" in result.output
