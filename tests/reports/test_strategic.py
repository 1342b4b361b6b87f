"""The strategic-evaluation figure: worlds with trajectories beside the random distribution."""

from __future__ import annotations

import jax
import numpy as np
from PIL import Image

from worldagent.agents.policy import harvest_random_policy, racing_driver_policy
from worldagent.envs.harvest import Harvest, make_params
from worldagent.envs.racing.env import ParticleRacing
from worldagent.evaluation.trajectories import replay, scored_keys, world_from_arrays
from worldagent.reports.strategic import ending_summary, strategic_figure, visit_counts
from worldagent.search.objectives import LatentObjective, Objective
from worldagent.store import Evaluation


def evaluations(env_name, env, policy, generator, metric, seeds, repeats=2):
    """Evaluations (with worlds) of two latents, as a campaign would store them."""
    objective = LatentObjective(Objective(env_name, metric, False), env, policy, generator, repeats)
    z = np.asarray(jax.random.normal(jax.random.key(4), (2, generator.latent_dim)))
    outcomes = objective(z, np.asarray(seeds))
    worlds = [{name: np.asarray(value) for name, value in vars(o.world).items()} for o in outcomes]
    made = [Evaluation("test", 0, i, z[i], o.score, o.episodes, 0.0, 0.0, worlds[i]) for i, o in enumerate(outcomes)]
    return sorted(made, key=lambda e: e.score)


def test_racing_figure_with_the_scored_episodes(tmp_path, racing_generator):
    env, policy = ParticleRacing(), racing_driver_policy()
    low, high = evaluations("racing", env, policy, racing_generator, "return", [5, 6])
    seeds = {0: 5, 1: 6}
    keys = tuple(scored_keys(seeds[e.slot], 2) for e in (low, high))
    out = strategic_figure("racing", env, policy, None, low, high, np.linspace(-300, 90, 50), "return", tmp_path / "s.png", key=keys)
    assert out.stat().st_size > 20_000
    with Image.open(out) as image:
        assert image.format == "PNG" and image.size[0] > 2 * image.size[1]
    episodes = replay(env, policy, world_from_arrays("racing", low.world), keys[0])
    assert ending_summary(episodes).startswith("2 episodes: ")


def test_harvest_figure_and_visit_counts(tmp_path, harvest_generator):
    env, policy, params = Harvest(), harvest_random_policy(), make_params()
    low, high = evaluations("harvest", env, policy, harvest_generator, "group_reward", [1, 2], repeats=1)
    out = strategic_figure("harvest", env, policy, params, low, high, np.arange(40.0), "group_reward", tmp_path / "h.png")
    assert out.stat().st_size > 20_000
    episodes = replay(env, policy, world_from_arrays("harvest", low.world), scored_keys(3, 2), params)
    counts = visit_counts(episodes, (25, 25))
    assert counts.shape == (4, 25, 25)
    np.testing.assert_array_equal(counts.sum(axis=(1, 2)), episodes.present.sum(axis=(0, 1)))  # one count per agent-step on the map
