"""Campaigns and the run store: immediate commits, exact resume, sharing, refusals."""

from __future__ import annotations

import sqlite3
import threading

import numpy as np
import pytest

from worldagent.errors import WorldagentError
from worldagent.search.campaign import CampaignSpec, Outcome, run_campaign
from worldagent.search.optimisers import OptimiserConfig
from worldagent.store import RunStore

CONFIG = OptimiserConfig(popsize=6, bo_batch=3, initial_points=4, bo_candidates=1000, bo_starts=1, random_batch=5)


def noisy_sphere(z, seeds):
    """A stochastic objective whose noise depends only on each evaluation's seed."""
    outcomes = []
    for latent, seed in zip(z, seeds):
        noise = np.random.default_rng(seed).normal(0, 0.1, size=3)
        episodes = [{"cost": float(np.sum((latent - 1) ** 2) + n)} for n in noise]
        outcomes.append(Outcome(float(np.mean([e["cost"] for e in episodes])), episodes))
    return outcomes


class Killed(Exception):
    """Stands in for the process being killed."""


def dying_after(calls):
    state = {"left": calls}

    def evaluate(z, seeds):
        if state["left"] == 0:
            raise Killed
        state["left"] -= 1
        return noisy_sphere(z, seeds)

    return evaluate


def spec(name="c", optimiser="cmaes", budget=30, **kw):
    return CampaignSpec(name=name, env="racing", objective="cost", maximize=False, optimiser=optimiser, budget=budget, seed=3, config=CONFIG, **kw)


def summary(evaluations):
    return [(e.generation, e.slot, tuple(np.round(e.latent, 12)), round(e.score, 12)) for e in evaluations]


@pytest.mark.parametrize("optimiser, budget", [("cmaes", 30), ("bo", 13), ("random", 30)])
def test_a_killed_campaign_resumes_to_exactly_the_uninterrupted_run(tmp_path, optimiser, budget):
    with RunStore(tmp_path / "a") as store:
        straight = run_campaign(store, spec(optimiser=optimiser, budget=budget, chunk=1), noisy_sphere, progress=False)
    with RunStore(tmp_path / "b") as store:
        with pytest.raises(Killed):  # killed in the middle of a generation
            run_campaign(store, spec(optimiser=optimiser, budget=budget, chunk=1), dying_after(8), progress=False)
        assert len(store.evaluations("c")) == 8  # everything finished was kept
        resumed = run_campaign(store, spec(optimiser=optimiser, budget=budget, chunk=1), noisy_sphere, resume=True, progress=False)
    assert summary(resumed) == summary(straight)
    assert len(straight) >= budget


def test_each_evaluation_is_committed_as_it_finishes(tmp_path):
    seen = []

    def watching(z, seeds):
        with RunStore(tmp_path) as reader:  # another connection sees earlier evaluations already
            seen.append(len(reader.evaluations("c")))
        return noisy_sphere(z, seeds)

    with RunStore(tmp_path) as store:
        run_campaign(store, spec(budget=12, chunk=2), watching, progress=False)
    assert seen == [0, 2, 4, 6, 8, 10]


def test_starting_an_existing_campaign_or_resuming_with_other_settings_is_refused(tmp_path):
    with RunStore(tmp_path) as store:
        run_campaign(store, spec(budget=6), noisy_sphere, progress=False)
        with pytest.raises(WorldagentError, match="--resume"):
            run_campaign(store, spec(budget=6), noisy_sphere, progress=False)
        other = CampaignSpec("c", "racing", "cost", True, "cmaes", 6, 3, config=CONFIG)
        with pytest.raises(WorldagentError, match="other settings \\(maximize\\)"):
            run_campaign(store, other, noisy_sphere, resume=True, progress=False)


def test_two_campaigns_share_a_store_and_readers_run_concurrently(tmp_path):
    errors = []

    def reader():
        try:
            for _ in range(30):
                with RunStore(tmp_path) as store:
                    store.evaluations()
        except Exception as error:  # pragma: no cover - the assertion below reports it
            errors.append(error)

    threads = [threading.Thread(target=reader) for _ in range(3)]
    for thread in threads:
        thread.start()
    with RunStore(tmp_path) as store:
        run_campaign(store, spec("min", budget=18), noisy_sphere, progress=False)
        run_campaign(store, spec("rand", optimiser="random", budget=10), noisy_sphere, progress=False)
    for thread in threads:
        thread.join()
    assert not errors
    with RunStore(tmp_path, create=False) as store:
        assert [c.name for c in store.campaigns()] == ["min", "rand"]
        assert len(store.evaluations("min")) == 18 and len(store.evaluations("rand")) == 10


def test_many_connections_opening_a_new_store_at_once_all_succeed(tmp_path):
    # SQLite refuses a second simultaneous switch of a new file to WAL without waiting.
    errors = []

    def open_store(path):
        try:
            with RunStore(path) as store:
                store.evaluations()
        except Exception as error:  # pragma: no cover - the assertion below reports it
            errors.append(error)

    for trial in range(40):
        threads = [threading.Thread(target=open_store, args=(tmp_path / str(trial),)) for _ in range(4)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
    assert not errors


def test_two_connections_creating_the_same_campaign_at_once_both_get_it(tmp_path):
    # Each read "no such campaign" and inserted it: the second insert broke UNIQUE(name) (issue 30, item 7).
    with RunStore(tmp_path):
        pass
    connections, trials = 4, 60
    barrier = threading.Barrier(connections, timeout=60)
    found: dict = {}  # (trial, resume) -> ids or errors

    def create():
        with RunStore(tmp_path) as store:  # a connection of its own, as another process has
            for trial in range(trials):
                resume = trial % 2 == 0
                barrier.wait()
                try:
                    outcome = store.open_campaign(f"c{trial}", "racing", "reward", True, "cmaes", 6, 0, {"popsize": 6}, resume).id
                except Exception as error:
                    outcome = error
                found.setdefault(trial, []).append(outcome)

    threads = [threading.Thread(target=create) for _ in range(connections)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    for trial, outcomes in sorted(found.items()):
        ids = {o for o in outcomes if isinstance(o, int)}
        refused = [o for o in outcomes if not isinstance(o, int)]
        if trial % 2 == 0:  # --resume: every one gets the one campaign
            assert len(outcomes) == connections and not refused and len(ids) == 1, outcomes
        else:  # one creates it; the others are told it exists (pass --resume)
            assert len(ids) == 1 and len(refused) == connections - 1, outcomes
            assert all(isinstance(e, WorldagentError) and "--resume" in str(e) for e in refused), outcomes
    assert len(found) == trials


def test_nan_scores_are_stored_and_reported_not_optimised(tmp_path):
    def broken(z, seeds):
        outcomes = noisy_sphere(z, seeds)
        outcomes[1] = Outcome(float("nan"), [{"cost": float("nan")}])
        return outcomes

    with RunStore(tmp_path) as store:
        with pytest.raises(WorldagentError, match="1 world\\(s\\) of generation 0 scored NaN"):
            run_campaign(store, spec(budget=12), broken, progress=False)
        stored = store.evaluations("c")
    assert len(stored) == 6 and np.isnan(stored[1].score) and np.isnan(stored[1].episodes[0]["cost"])


def test_foreign_and_malformed_store_files_are_refused(tmp_path):
    garbage = tmp_path / "garbage.sqlite"
    garbage.write_bytes(b"this is not a database" * 100)
    foreign = tmp_path / "foreign.sqlite"
    with sqlite3.connect(foreign) as db:
        db.execute("CREATE TABLE stuff (x)")
    for path, message in ((garbage, "not a worldagent run store"), (foreign, "not a worldagent run store")):
        with pytest.raises(WorldagentError, match=message):
            RunStore(path)
    with pytest.raises(WorldagentError, match="no run store"):
        RunStore(tmp_path / "nowhere.sqlite", create=False)


def test_store_exports_csv_and_round_trips_worlds(tmp_path):
    from worldagent.envs.harvest.world import empty_map

    world = empty_map(5)
    with RunStore(tmp_path) as store:
        campaign = store.open_campaign("w", "harvest", "group_reward", True, "random", 1, 0, {}, False)
        store.add(campaign, 0, 0, np.zeros(10), 3.0, [{"group_reward": 2.0}, {"group_reward": 4.0}], 0.0, world)
        [evaluation] = store.evaluations("w", with_worlds=True)
        np.testing.assert_array_equal(evaluation.world["walls"], world.walls)
        text = store.export_csv(tmp_path / "w.csv").read_text().splitlines()
    assert text[0].startswith("campaign,generation,slot,score,mean_group_reward,episodes,z0")
    assert text[1].startswith("w,0,0,3.0,3.0,2,0.0")


def test_store_deletes_campaigns_with_their_evaluations(tmp_path):
    with RunStore(tmp_path) as store:
        for name in ("a", "b"):
            campaign = store.open_campaign(name, "racing", "return", True, "random", 1, 0, {}, False)
            store.add(campaign, 0, 0, np.zeros(2), 1.0, [{"return": 1.0}], 0.0)
        assert store.delete_campaigns(["a", "missing"]) == 1
        assert [c.name for c in store.campaigns()] == ["b"] and [e.campaign for e in store.evaluations()] == ["b"]
        assert store.delete_campaigns([]) == 0
        store.open_campaign("a", "racing", "return", True, "random", 1, 0, {}, False)  # the name is free again


def test_the_best_evaluation_is_the_earliest_extreme_finite_score():
    from worldagent.search.campaign import best_evaluation
    from worldagent.store import Evaluation

    def ev(slot, score):
        return Evaluation("c", 0, slot, np.zeros(2), score, [], 0.0, 0.0)

    evaluations = [ev(0, float("nan")), ev(1, 2.0), ev(2, 1.0), ev(3, 1.0), ev(4, 5.0)]
    assert best_evaluation(evaluations, maximize=False).slot == 2
    assert best_evaluation(evaluations, maximize=True).slot == 4
    assert best_evaluation([ev(0, float("nan"))], maximize=True) is None
