"""The paper's evaluation experiments as library calls: strategic evaluation, optimiser comparison."""

from __future__ import annotations

import numpy as np
import pytest

from worldagent.agents.policy import racing_driver_policy
from worldagent.envs.racing.env import ParticleRacing
from worldagent.errors import WorldagentError
from worldagent.evaluation.trajectories import replay, world_from_arrays
from worldagent.search.experiments import compare_optimisers, random_evaluation, strategic_evaluation
from worldagent.search.optimisers import OptimiserConfig
from worldagent.store import RunStore

RACING = ParticleRacing()
SMALL = OptimiserConfig(popsize=6, bo_batch=3, random_batch=5)


def finished_times(store: RunStore) -> list[float]:
    return sorted(e.finished for e in store.evaluations())


def test_strategic_evaluation_finds_a_min_below_its_max_and_resumes(tmp_path, racing_generator):
    policy = racing_driver_policy()
    args = (RACING, policy, racing_generator, RACING.default_params, "return")
    with RunStore(tmp_path) as store:
        found = strategic_evaluation(store, "racing", *args, budget=12, repeats=2, seed=3, progress=False, config=SMALL)
        assert found["campaigns"] == ["cmaes-min-return-s3", "cmaes-max-return-s3"]
        assert found["min"].score <= found["max"].score
        lows = [e.score for e in store.evaluations("cmaes-min-return-s3")]
        assert len(lows) == 12 and found["min"].score == min(lows)
        assert found["max"].score == max(e.score for e in store.evaluations("cmaes-max-return-s3"))
        before = finished_times(store)
        again = strategic_evaluation(store, "racing", *args, budget=12, repeats=2, seed=3, progress=False)  # stored settings are reused
        assert finished_times(store) == before  # nothing new evaluated
        assert again["min"].score == found["min"].score and again["max"].score == found["max"].score
    for direction, keys in zip(("min", "max"), found["keys"]):  # the keys replay the scored episodes
        evaluation = found[direction]
        episodes = replay(RACING, policy, world_from_arrays("racing", evaluation.world), keys)
        assert episodes.metrics["return"].mean() == pytest.approx(evaluation.score, abs=1e-3)


def test_compare_optimisers_gives_equal_budgets_in_evaluation_order(tmp_path, racing_generator):
    args = (RACING, racing_driver_policy(), racing_generator, RACING.default_params, "return")
    kwargs = dict(optimisers=("cmaes", "bo", "random"), budget=8, seeds=(0, 1), repeats=2, progress=False, config=SMALL)
    with RunStore(tmp_path) as store:
        runs = compare_optimisers(store, "racing", *args, **kwargs)
        assert list(runs) == ["cmaes", "bo", "random"] and all(len(seeds) == 2 for seeds in runs.values())
        assert all(scores.shape == (8,) for seeds in runs.values() for scores in seeds)  # CMA-ES ran 12: only 8 count
        stored = [e.score for e in store.evaluations("compare-cmaes-min-return-s1")]
        assert len(stored) == 12
        np.testing.assert_array_equal(runs["cmaes"][1], stored[:8])
        assert not np.array_equal(runs["random"][0], runs["random"][1])  # seeds differ
        before = finished_times(store)
        again = compare_optimisers(store, "racing", *args, **kwargs)
        assert finished_times(store) == before
        for name in runs:
            for first, second in zip(runs[name], again[name]):
                np.testing.assert_array_equal(first, second)


def test_random_evaluation_reuses_a_larger_campaign(tmp_path, racing_generator):
    args = (RACING, racing_driver_policy(), racing_generator, RACING.default_params, "return")
    with RunStore(tmp_path) as store:
        ten = random_evaluation(store, "racing", *args, worlds=10, repeats=2, seed=4, progress=False)
        before = finished_times(store)
        six = random_evaluation(store, "racing", *args, worlds=6, repeats=2, seed=4, progress=False)
        assert finished_times(store) == before and [e.score for e in six] == [e.score for e in ten[:6]]
        more = random_evaluation(store, "racing", *args, worlds=14, repeats=2, seed=4, progress=False)  # resumed, 4 new
        assert len(more) == 14 and [e.score for e in more[:10]] == [e.score for e in ten]
        assert store.campaign("random-return-s4").budget == 14


def test_bad_requests_are_refused(tmp_path, racing_generator):
    args = (RACING, racing_driver_policy(), racing_generator, RACING.default_params, "return")
    with RunStore(tmp_path) as store:
        with pytest.raises(WorldagentError, match="unknown optimiser 'sgd'"):
            compare_optimisers(store, "racing", *args, optimisers=("sgd",), budget=4)
        with pytest.raises(WorldagentError, match="at least one random world"):
            random_evaluation(store, "racing", *args, worlds=0)
        with pytest.raises(WorldagentError, match="no metric 'speed'"):
            strategic_evaluation(store, "racing", *args[:-1], "speed", budget=4)
