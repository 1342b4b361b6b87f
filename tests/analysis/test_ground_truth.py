"""Confirmation against ground truth (issue 50, item 5): worlds whose failure probability p(w) is known exactly.

Each of 200 seeds is a search that scores 16 coins (``tests/coin_env``: an episode fails with the world's p) on 8
episodes and picks the worst; the pick is confirmed on 64 fresh episodes. The found figure carries the winner's
curse (it is above the pick's true p on average); the confirmed interval covers the true p as a 95% interval
should; a world that never fails is never confirmed failing.
"""

from __future__ import annotations

import numpy as np
import pytest

from coin_env import coins, registered
from worldagent import experiments
from worldagent.analysis import confirm as confirmation
from worldagent.events import parse_selection
from worldagent.search.campaign import evaluation_seed
from worldagent.search.given import GivenWorlds
from worldagent.search.objectives import Objective
from worldagent.store import Evaluation, RunStore

pytestmark = pytest.mark.integration  # whole-pipeline work: .ci/run's integration step runs it

SEEDS, WORLDS, REPEATS = 200, 16, 8
NEVER = 20  # more searches whose 16 coins all have p = 0


@pytest.fixture(scope="module")
def picked(tmp_path_factory):
    """(true p of each pick, its ConfirmedWorld, the failure event) over all the searches."""
    with registered() as spec, pytest.MonkeyPatch.context() as patch:
        # one-step episodes: play them thousands to a call (the suite's 16 would take thousands of calls)
        patch.setenv("WORLDAGENT_EPISODES_PER_CALL", "4096")
        patch.setattr(confirmation, "BATCH", (SEEDS + NEVER) // 2)  # two calls of one shape
        setup = experiments.setup(spec.name, "idle", None, repeats=REPEATS)
        rng = np.random.default_rng(50)
        p = np.concatenate([rng.uniform(0.0, 0.6, SEEDS * WORLDS), np.zeros(NEVER * WORLDS)])
        worlds = coins(p)
        score = GivenWorlds(Objective(spec.name, "failed", True), setup.env, setup.policy, worlds, REPEATS, setup.params)
        searches = SEEDS + NEVER
        seeds = np.array([evaluation_seed(s, 0, i) for s in range(searches) for i in range(WORLDS)])
        outcomes = score(np.arange(len(p))[:, None], seeds)  # every search's worlds on 8 episodes, in one program
        picks, truth = [], []
        for s in range(searches):
            mine = range(s * WORLDS, (s + 1) * WORLDS)
            worst = max(mine, key=lambda i: (outcomes[i].score, -i))  # the most failures, the earliest on ties
            world = spec.world_to_arrays(type(worlds)(p=worlds.p[worst], tag=worlds.tag[worst]))
            picks.append(
                Evaluation(f"search-s{s}", 0, worst - s * WORLDS, np.zeros(0), outcomes[worst].score, outcomes[worst].episodes, 0.0, 0.0, world)
            )
            truth.append(float(np.float32(p[worst])))
        with RunStore(tmp_path_factory.mktemp("truth")) as store:
            confirmed = confirmation.confirm(store, setup, picks, name="worst of 16", repeats=64, seed=0, progress=False)
        yield np.array(truth), confirmed, parse_selection(spec.failure, spec.name)


def test_the_confirmed_interval_covers_the_true_failure_probability(picked):
    truth, confirmed, _ = picked
    intervals = [c.confirmed("failed") for c in confirmed[:SEEDS]]
    covered = np.mean([i.low <= p <= i.high for i, p in zip(intervals, truth[:SEEDS])])
    assert covered >= 0.93
    assert all(i.n == 64 for i in intervals) and len({c.digest for c in confirmed[:SEEDS]}) == SEEDS


def test_the_found_figure_carries_the_winners_curse_and_the_confirmed_one_does_not(picked):
    truth, confirmed, _ = picked
    found = np.array([c.found("failed").mean for c in confirmed[:SEEDS]])
    fresh = np.array([c.confirmed("failed").mean for c in confirmed[:SEEDS]])
    bias, residual = found - truth[:SEEDS], fresh - truth[:SEEDS]
    # the worst of 16 noisy scores: far above its world's p on average, and more than noise explains
    assert bias.mean() > 0.1 and bias.mean() > 5 * bias.std() / np.sqrt(SEEDS)
    assert abs(residual.mean()) < 3 * residual.std() / np.sqrt(SEEDS) + 0.005  # unbiased within its noise


def test_a_world_that_never_fails_is_never_confirmed_failing(picked):
    truth, confirmed, event = picked
    never = [c for c, p in zip(confirmed, truth) if p == 0]
    assert len(never) >= NEVER and all(c.confirmed("failed").mean == 0 for c in never)
    assert not any(c.holds(event) for c in never)
    # the event on found figures calls worlds failing that are not; on confirmed ones it rarely does
    false_found = sum(bool(event.mask([c.selected])[0]) for c, p in zip(confirmed, truth) if p <= 0.5)
    false_confirmed = sum(c.holds(event) for c, p in zip(confirmed, truth) if p <= 0.5)
    assert false_confirmed <= 0.05 * SEEDS < false_found
