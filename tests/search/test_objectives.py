"""Scoring latents: G(z), 8 episodes, the metric's mean; campaigns over real worlds and agents."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from worldagent.agents.loaders import scripted_policy
from worldagent.agents.policy import Policy
from worldagent.envs.racing.env import ParticleRacing
from worldagent.errors import WorldagentError
from worldagent.search.campaign import CampaignSpec, run_campaign
from worldagent.search.objectives import LatentObjective, Objective
from worldagent.search.optimisers import OptimiserConfig
from worldagent.store import RunStore

RACING = ParticleRacing()


def random_policy():
    return Policy(None, lambda params, obs, key, state=None: jax.random.randint(key, (), 0, 4), "random")


def test_a_latents_score_is_the_metrics_mean_over_its_episodes(racing_generator):
    objective = LatentObjective(Objective("racing", "return", False), RACING, random_policy(), racing_generator, repeats=4)
    z = np.asarray(jax.random.normal(jax.random.key(0), (3, racing_generator.latent_dim)))
    outcomes = objective(z, np.array([11, 12, 13]))
    assert len(outcomes) == 3 and all(len(o.episodes) == 4 for o in outcomes)
    for outcome in outcomes:
        assert outcome.score == pytest.approx(np.mean([e["return"] for e in outcome.episodes]))
        assert all(0.0 <= e["normalised_return"] <= 1.0 for e in outcome.episodes)
    expected = racing_generator(z)
    np.testing.assert_array_equal(outcomes[1].world.centreline, np.asarray(expected.centreline[1]))
    again = objective(z, np.array([11, 12, 13]))
    assert [o.score for o in again] == [o.score for o in outcomes]  # a function of (z, seed)
    other = objective(z, np.array([21, 22, 23]))
    assert [o.score for o in other] != [o.score for o in outcomes]


def test_a_campaign_over_generated_worlds_stores_worlds_and_episodes(tmp_path, racing_generator):
    objective = LatentObjective(Objective("racing", "crashed", True), RACING, scripted_policy("racing", "driver"), racing_generator, repeats=2)
    spec = CampaignSpec("max-crash", "racing", "crashed", True, "cmaes", 12, 0, config=OptimiserConfig(popsize=6))
    with RunStore(tmp_path) as store:
        evaluations = run_campaign(store, spec, objective, progress=False)
        stored = store.evaluations("max-crash", with_worlds=True)
    assert len(evaluations) == 12
    assert stored[0].world["centreline"].shape == (256, 2)
    assert all(len(e.episodes) == 2 and set(e.episodes[0]) >= {"crashed", "return", "normalised_return"} for e in stored)


def test_an_objective_takes_the_specs_metric_names_and_aliases():
    assert Objective("racing", "reward", True).metric == "return"
    assert Objective("racing", "crash_rate", True).metric == "crashed"
    assert Objective("harvest", "reward", False).metric == "group_reward"


def test_bad_objectives_are_refused(racing_generator, harvest_generator):
    with pytest.raises(WorldagentError, match="no metric 'speed'"):
        Objective("racing", "speed", True)
    with pytest.raises(WorldagentError, match="unknown environment 'boats'"):
        Objective("boats", "return", True)
    with pytest.raises(WorldagentError, match="makes harvest worlds"):
        LatentObjective(Objective("racing", "return", True), RACING, random_policy(), harvest_generator)
