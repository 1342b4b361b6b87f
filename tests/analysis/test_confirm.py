"""Confirmation (analysis.confirm): fresh keys no search draws, found beside confirmed, resumable, one stream per campaign."""

from __future__ import annotations

import numpy as np
import pytest

from killed_backend import DiesAfter
from worldagent import experiments
from worldagent.analysis.confirm import (
    Interval,
    clause_confirmed,
    confirm,
    confirmation_keys,
    confirmation_seed,
    confirmed_summary,
    mean_interval,
)
from worldagent.events import parse_selection
from worldagent.identity import agent_identity
from worldagent.search.campaign import CampaignSpec, Outcome, evaluation_seed, run_campaign, stored_seed
from worldagent.search.objectives import search_keys
from worldagent.search.optimisers import OptimiserConfig
from worldagent.store import RunStore

SMALL = OptimiserConfig(popsize=6, random_batch=6)


@pytest.fixture(scope="module")
def racing(racing_generator):
    return experiments.setup("racing", "driver", racing_generator, repeats=2)


def key_data(keys) -> set[tuple[int, ...]]:
    import jax

    return {tuple(int(x) for x in row) for row in np.asarray(jax.random.key_data(keys)).reshape(len(keys), -1)}


def test_confirmation_keys_are_disjoint_from_every_search_key_and_repeat_for_the_same_world(tmp_path, racing):
    with RunStore(tmp_path) as store:
        randoms = experiments.random_evaluation(store, racing, "return", worlds=12, seed=0, progress=False)
        low, _ = experiments.search(store, racing, "return", maximize=False, optimiser="cmaes", budget=12, seed=0, progress=False, config=SMALL)
        picks = [experiments.best(low, False), experiments.best(randoms, False)]
        confirmed = confirm(store, racing, picks, name="test", repeats=16, seed=0, progress=False)
        searched = set()
        for campaign in store.campaigns():
            for e in store.evaluations(campaign.name):
                searched |= key_data(search_keys(stored_seed(campaign, e.generation, e.slot), len(e.episodes)))
        fresh = set().union(*(key_data(confirmation_keys(c.seed, c.repeats)) for c in confirmed))
        assert len(searched) == 24 * 2 and len(fresh) == 16 * len({c.digest for c in confirmed})
        assert searched.isdisjoint(fresh)
        again = confirm(store, racing, picks[:1], name="other", repeats=16, seed=0, progress=False)  # read back, same episodes
        assert again[0].episodes == confirmed[0].episodes and len(store.confirmations()) == len({c.digest for c in confirmed})
        assert [s.name for s in store.selections()] == ["test", "test", "other"]
        assert confirmed[0].found("return").mean == pytest.approx(picks[0].score) and confirmed[0].confirmed("return").n == 16


def test_a_killed_confirmation_resumes_to_the_rows_of_an_uninterrupted_one(tmp_path, racing, monkeypatch):
    import dataclasses

    from worldagent.analysis import confirm as module

    monkeypatch.setattr(module, "BATCH", 2)  # several batches of a few worlds
    rows = {}
    for name, backend in (("straight", None), ("killed", DiesAfter(1))):
        with RunStore(tmp_path / name) as store:
            found = experiments.random_evaluation(store, racing, "return", worlds=12, seed=0, progress=False)
            killed = dataclasses.replace(racing, backend=backend)
            if backend is not None:
                with pytest.raises(KeyboardInterrupt):
                    confirm(store, killed, found, name="all", repeats=4, seed=0, progress=False)
                assert len(store.confirmations()) == 2
            confirm(store, racing, found, name="all", repeats=4, seed=0, progress=False)
            rows[name] = sorted((c.world, c.seed, c.repeats, str(c.episodes)) for c in store.confirmations())
    assert rows["killed"] == rows["straight"] and len(rows["straight"]) > 1


def test_intervals_and_verdicts():
    assert mean_interval([0, 0, 0, 0]).high == pytest.approx(1 - 0.025 ** (1 / 4))  # Clopper-Pearson, k = 0
    assert mean_interval([1.0, 2.0, 3.0]).low == pytest.approx(2 - 4.302653 * 1 / np.sqrt(3), rel=1e-5)
    assert mean_interval([5.0, 5.0]) == Interval(5.0, 5.0, 5.0, 2)
    crash = parse_selection("crash_rate > 0.5", "racing").clauses[0]
    assert clause_confirmed(crash, [1] * 45 + [0] * 19)  # 45/64: [0.58, 0.81]
    assert not clause_confirmed(crash, [1] * 5 + [0] * 3)  # 5/8: [0.24, 0.91]
    calm = parse_selection("conflict == 0", "harvest").clauses[0]
    assert clause_confirmed(calm, [0.0] * 32) and not clause_confirmed(calm, [0.0] * 31 + [2.0])


def test_confirmation_seeds_depend_on_the_run_seed_and_the_world():
    a, b = "0" * 64, "f" * 64
    assert len({confirmation_seed(0, a), confirmation_seed(1, a), confirmation_seed(0, b)}) == 3
    assert confirmation_seed(0, a) == confirmation_seed(0, a)


def test_campaigns_that_share_a_seed_draw_other_episodes_and_old_ones_resume_on_the_old_rule(tmp_path):
    def evaluate(z, seeds):
        return [Outcome(float(s), [{"cost": float(s)}]) for s in seeds]

    spec = lambda name: CampaignSpec(name, "racing", "cost", False, "random", 6, 0, 3, SMALL)  # noqa: E731
    with RunStore(tmp_path) as store:
        first = run_campaign(store, spec("a"), evaluate, progress=False)
        second = run_campaign(store, spec("b"), evaluate, progress=False)
        assert not {e.score for e in first} & {e.score for e in second}
        # a campaign stored before streams (no "stream" in its config) resumes with stream 0
        config = {k: v for k, v in store.campaign("a").config.items() if k != "stream"}
        store.open_campaign("old", "racing", "cost", False, "random", 6, 0, config, resume=False)
        old = run_campaign(store, spec("old"), evaluate, resume=True, progress=False)
        assert [e.score for e in old] == [float(evaluation_seed(0, e.generation, e.slot)) for e in old]
        assert summary_of(store, "old") == [stored_seed(store.campaign("old"), e.generation, e.slot) for e in old]


def summary_of(store, name):
    return [int(e.score) for e in store.evaluations(name)]


def test_two_functions_of_one_module_are_two_agents():
    one = {"kind": "callable", "path": "mod:driver", "sha256": "abc"}
    assert agent_identity(one) != agent_identity({**one, "path": "mod:sbend_blind"})
    assert agent_identity(one) == agent_identity({**one, "path": "mod:driver"})
    saved = {"kind": "worldagent", "path": "/a/run", "sha256": "f00"}
    assert agent_identity(saved) == agent_identity({**saved, "path": "/elsewhere/run"})  # moved, same files


def test_agents_built_in_python_are_known_by_their_parameters_too():
    import jax.numpy as jnp

    from worldagent.agents.policy import Policy, agent_record

    act = lambda params, obs, key, state: jnp.argmax(params @ obs)  # noqa: E731
    one, other = Policy(jnp.eye(2), act, name="trained"), Policy(2 * jnp.eye(2), act, name="trained")
    assert agent_identity(agent_record(one)) != agent_identity(agent_record(other))
    assert agent_identity(agent_record(one)) == agent_identity(agent_record(Policy(jnp.eye(2), act, name="trained")))


def test_summary_counts_distinct_worlds_and_confirmed_failures(tmp_path, racing):
    with RunStore(tmp_path) as store:
        found = experiments.random_evaluation(store, racing, "return", worlds=6, seed=0, progress=False)
        picks = found[:3] + found[:1]  # one world picked twice
        confirmed = confirm(store, racing, picks, name="x", repeats=4, seed=0, progress=False)
    event = parse_selection("return < 1e9", "racing")  # every episode "fails": the count is exact
    summary = confirmed_summary(confirmed, event)
    assert summary["picked"] == 4 and summary["distinct_worlds"] == len({c.digest for c in confirmed}) <= 3
    assert summary["found_failing"] == summary["distinct_worlds"] and summary["confirmation_episodes"] == 4 * summary["distinct_worlds"]
    assert summary["confirmed_failing"] == summary["distinct_worlds"]


def test_a_campaign_of_an_agent_recorded_before_parameters_were_hashed_resumes(tmp_path):
    def evaluate(z, seeds):
        return [Outcome(float(s), [{"cost": float(s)}]) for s in seeds]

    old = {"kind": "python", "path": "trained", "sha256": None}
    new = {**old, "sha256": "ab12"}
    with RunStore(tmp_path) as store:
        run_campaign(store, CampaignSpec("c", "racing", "cost", False, "random", 6, 0, 3, SMALL, agent=old), evaluate, progress=False)
        again = run_campaign(
            store, CampaignSpec("c", "racing", "cost", False, "random", 12, 0, 3, SMALL, agent=new), evaluate, resume=True, progress=False
        )
        assert len(again) == 12
        with pytest.raises(Exception, match="other settings"):  # a hashed agent is not resumed by another one
            run_campaign(store, CampaignSpec("d", "racing", "cost", False, "random", 6, 0, 3, SMALL, agent=new), evaluate, progress=False)
            run_campaign(
                store,
                CampaignSpec("d", "racing", "cost", False, "random", 6, 0, 3, SMALL, agent={**new, "sha256": "cd34"}),
                evaluate,
                resume=True,
                progress=False,
            )
