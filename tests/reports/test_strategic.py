"""The strategic-evaluation figure: worlds with trajectories (``spec.pictures.episodes``) beside the random distribution."""

from __future__ import annotations

import jax
import numpy as np
from PIL import Image

from worldagent.agents.loaders import load_agent
from worldagent.envs import registry
from worldagent.evaluation.trajectories import replay, scored_keys
from worldagent.reports.strategic import ending_summary, strategic_figure
from worldagent.search.objectives import LatentObjective, Objective
from worldagent.store import Evaluation


def evaluations(spec, env, policy, params, generator, metric, seeds, repeats=2):
    """Evaluations (with worlds) of two latents, as a campaign would store them."""
    objective = LatentObjective(Objective(spec.name, metric, False), env, policy, generator, repeats, params)
    z = np.asarray(jax.random.normal(jax.random.key(4), (2, generator.latent_dim)))
    outcomes = objective(z, np.asarray(seeds))
    worlds = [spec.world_to_arrays(o.world) for o in outcomes]
    made = [Evaluation("test", 0, i, z[i], o.score, o.episodes, 0.0, 0.0, worlds[i]) for i, o in enumerate(outcomes)]
    return sorted(made, key=lambda e: e.score)


def test_racing_figure_with_the_scored_episodes(tmp_path, racing_generator):
    spec = registry.get("racing")
    env, params = spec.make_env()
    policy = load_agent(spec, "driver")
    low, high = evaluations(spec, env, policy, params, racing_generator, "return", [5, 6])
    seeds = {0: 5, 1: 6}
    keys = tuple(scored_keys(seeds[e.slot], 2) for e in (low, high))
    out = strategic_figure("racing", env, policy, None, low, high, np.linspace(-300, 90, 50), "return", tmp_path / "s.png", key=keys)
    assert out.stat().st_size > 20_000
    with Image.open(out) as image:
        assert image.format == "PNG" and image.size[0] > 2 * image.size[1]
    episodes = replay(spec, env, policy, spec.world_from_arrays(low.world), keys[0])
    assert ending_summary(spec, episodes).startswith("2 episodes (steps ") and "episodes crashed" in ending_summary(spec, episodes)


def test_harvest_figure(tmp_path, harvest_generator):
    spec = registry.get("harvest")
    env, params = spec.make_env()
    policy = load_agent(spec, "random")
    low, high = evaluations(spec, env, policy, params, harvest_generator, "group_reward", [1, 2], repeats=1)
    out = strategic_figure(spec, env, policy, params, low, high, np.arange(40.0), "group_reward", tmp_path / "h.png")
    assert out.stat().st_size > 20_000
