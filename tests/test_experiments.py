"""The library of experiments: setup, search, random and strategic evaluation, optimiser comparison."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from worldagent import experiments
from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.evaluation.trajectories import replay
from worldagent.experiments import compare_optimisers, random_evaluation, setup, strategic_evaluation
from worldagent.search.optimisers import OptimiserConfig
from worldagent.store import RunStore

SMALL = OptimiserConfig(popsize=6, bo_batch=3, random_batch=5)


def finished_times(store: RunStore) -> list[float]:
    return sorted(e.finished for e in store.evaluations())


@pytest.fixture(scope="module")
def racing(racing_generator):
    return setup("racing", "driver", racing_generator, repeats=2)


def test_setup_resolves_env_agent_and_generator(racing, racing_generator, harvest_generator):
    assert racing.spec.name == "racing" and racing.policy.name == "driver" and racing.generator is racing_generator
    assert racing.metric("reward") == "return" and racing.metric("crash_rate") == "crashed"
    harvest = setup("harvest", "random", harvest_generator, options={"tagger": (0,)})
    assert (
        harvest.options == registry.get("harvest").check_options({"tagger": (0,)})
        and harvest.options["tagger"] == (0,)
        and bool(harvest.params.can_tag[0])
        and harvest.repeats == 8
    )
    with pytest.raises(WorldagentError, match="makes racing worlds; pass a harvest generator"):
        setup("harvest", "random", racing_generator)
    with pytest.raises(WorldagentError, match="unknown environment 'boats'"):
        setup("boats", "random", racing_generator)
    with pytest.raises(WorldagentError, match="no option 'speed'"):
        setup("racing", "driver", racing_generator, options={"speed": 1})
    with pytest.raises(WorldagentError, match="repeats=0"):
        setup("racing", "driver", racing_generator, repeats=0)


def test_campaign_names_are_made_in_one_place():
    assert experiments.campaign_names("return", 3) == {"random": "random-return-s3", "min": "cmaes-min-return-s3", "max": "cmaes-max-return-s3"}
    assert experiments.comparison_campaign_name("bo", False, "return", 1) == "compare-bo-min-return-s1"
    assert experiments.comparison_campaign_names("conflict", (0, 1), ("random",), True) == {
        "random": ["compare-random-max-conflict-s0", "compare-random-max-conflict-s1"]
    }


def test_search_names_its_campaign_and_refuses_a_second_without_resume(tmp_path, racing):
    with RunStore(tmp_path) as store:
        evaluations, spec = experiments.search(
            store, racing, "crash_rate", maximize=True, optimiser="random", budget=5, seed=2, progress=False, config=SMALL
        )
        assert spec.name == "random-max-crashed-s2" and spec.objective == "crashed" and len(evaluations) == 5
        with pytest.raises(WorldagentError, match="already exists"):
            experiments.search(store, racing, "crashed", maximize=True, optimiser="random", budget=5, seed=2, progress=False)
        again, _ = experiments.search(store, racing, "crashed", maximize=True, optimiser="random", budget=5, seed=2, resume=True, progress=False)
        assert [e.score for e in again] == [e.score for e in evaluations]


def test_strategic_evaluation_finds_a_min_below_its_max_and_resumes(tmp_path, racing):
    with RunStore(tmp_path) as store:
        found = strategic_evaluation(store, racing, budget=12, seed=3, progress=False, config=SMALL)
        assert found["campaigns"] == ["cmaes-min-return-s3", "cmaes-max-return-s3"] and found["metric"] == "return"
        assert found["min"].score <= found["max"].score
        lows = [e.score for e in store.evaluations("cmaes-min-return-s3")]
        assert len(lows) == 12 and found["min"].score == min(lows)
        assert found["max"].score == max(e.score for e in store.evaluations("cmaes-max-return-s3"))
        assert all(note.endswith("episodes crashed") for note in found["notes"])  # racing's episode_note
        before = finished_times(store)
        again = strategic_evaluation(store, racing, budget=12, seed=3, progress=False)  # stored settings are reused
        assert finished_times(store) == before  # nothing new evaluated
        assert again["min"].score == found["min"].score and again["max"].score == found["max"].score
    for direction, keys in zip(("min", "max"), found["keys"]):  # the keys replay the scored episodes
        evaluation = found[direction]
        world = racing.spec.world_from_arrays(evaluation.world)
        episodes = replay(racing.spec, racing.env, racing.policy, world, keys, racing.params)
        assert episodes.metrics["return"].mean() == pytest.approx(evaluation.score, abs=1e-3)


def test_compare_optimisers_gives_equal_budgets_in_evaluation_order(tmp_path, racing):
    kwargs = dict(optimisers=("cmaes", "bo", "random"), budget=8, budgets={"bo": 3}, seeds=(0, 1), progress=False, config=SMALL)
    with RunStore(tmp_path) as store:
        runs = compare_optimisers(store, racing, "return", **kwargs)
        assert list(runs) == ["cmaes", "bo", "random"] and all(len(seeds) == 2 for seeds in runs.values())
        assert [scores.shape for scores in runs["cmaes"] + runs["random"]] == [(8,)] * 4  # CMA-ES ran 12: only 8 count
        assert [scores.shape for scores in runs["bo"]] == [(3,)] * 2  # its own budget
        stored = [e.score for e in store.evaluations("compare-cmaes-min-return-s1")]
        assert len(stored) == 12
        np.testing.assert_array_equal(runs["cmaes"][1], stored[:8])
        assert not np.array_equal(runs["random"][0], runs["random"][1])  # seeds differ
        before = finished_times(store)
        again = compare_optimisers(store, racing, "return", **kwargs)
        assert finished_times(store) == before
        for name in runs:
            for first, second in zip(runs[name], again[name]):
                np.testing.assert_array_equal(first, second)


def test_random_evaluation_reuses_a_larger_campaign(tmp_path, racing):
    with RunStore(tmp_path) as store:
        ten = random_evaluation(store, racing, worlds=10, seed=4, progress=False)
        before = finished_times(store)
        six = random_evaluation(store, racing, "return", worlds=6, seed=4, progress=False)
        assert finished_times(store) == before and [e.score for e in six] == [e.score for e in ten[:6]]
        more = random_evaluation(store, racing, worlds=14, seed=4, progress=False)  # resumed, 4 new
        assert len(more) == 14 and [e.score for e in more[:10]] == [e.score for e in ten]
        assert store.campaign("random-return-s4").budget == 14
        np.testing.assert_array_equal(experiments.random_scores(store, "return", 4), [e.score for e in more])


def test_bad_requests_are_refused(tmp_path, racing):
    with RunStore(tmp_path) as store:
        with pytest.raises(WorldagentError, match="unknown optimiser 'sgd'"):
            compare_optimisers(store, racing, optimisers=("sgd",), budget=4)
        with pytest.raises(WorldagentError, match="unknown optimiser 'sgd'"):
            compare_optimisers(store, racing, budget=4, budgets={"sgd": 2})
        with pytest.raises(WorldagentError, match="at least one random world"):
            random_evaluation(store, racing, worlds=0)
        with pytest.raises(WorldagentError, match="no metric 'speed'"):
            strategic_evaluation(store, racing, "speed", budget=4)
        with pytest.raises(WorldagentError, match="no world of the campaign has a finite score"):
            experiments.best([dataclasses.replace(e, score=float("nan")) for e in store.evaluations()] or [], True)
