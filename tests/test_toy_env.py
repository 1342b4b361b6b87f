"""Proof of extensibility (issue 11, item 7): a third environment, defined in ``tests/toy_env``
and registered through the public API only, runs every phase of worldagent with no edit to it.

Two routes: ``reproduce`` of the tiny preset (dataset, generator, agent, random, strategic,
influence) with its report, which must hold a toy section with numbers (the default run, ~30 s
on 2 idle cores); and the library, each phase a direct call into ``worldagent.experiments``
(``-m slow``: the same phases again, through the API a notebook would use).
"""

from __future__ import annotations

import math
import re

import jax
import numpy as np
import pytest

import toy_env
from worldagent.errors import WorldagentError


@pytest.fixture(scope="module")
def toy():
    with toy_env.registered() as spec:
        yield spec


@pytest.fixture(scope="module")
def toy_generator(toy, tmp_path_factory):
    """(generator, dataset path): a tiny VAE on 256 toy worlds."""
    from worldagent.worlds.dataset import make_dataset
    from worldagent.worlds.generator import build_generator
    from worldagent.worlds.vae import VAEConfig, train_vae

    dataset = make_dataset(toy.name, 256, 0, progress=False)
    assert dataset.env == toy.name and dataset.cells.shape == (256, toy.cell_count)
    path = dataset.save(tmp_path_factory.mktemp("toy") / "dataset.npz")
    vae = train_vae(dataset, VAEConfig(encoder=(64, 32), decoder=(32, 64), epochs=3, batch_size=32, warmup_epochs=1), progress=False)
    return build_generator(vae, dataset), path


def test_the_toy_is_registered_through_the_public_api_only(toy):
    from worldagent.envs import registry

    assert toy.name in registry.names() and registry.get(toy.name) is toy
    with pytest.raises(WorldagentError):
        registry.register(toy_env.SPEC.__class__(**{**vars(toy_env.SPEC)}))  # a second "toy" is refused


@pytest.mark.slow  # the reproduce route below builds and uses the toy's generator in the default run
def test_generator_makes_valid_toy_worlds(toy, toy_generator):
    generator, _ = toy_generator
    assert generator.env == toy.name
    worlds = generator(jax.random.normal(jax.random.key(0), (16, generator.latent_dim)))
    env, _ = toy.make_env()
    for index in range(16):
        env.check_world(jax.tree_util.tree_map(lambda leaf: np.asarray(leaf[index]), worlds))


@pytest.mark.slow  # ~30 s on 2 idle cores; the reproduce route below runs the same phases in the default run
def test_library_route_train_search_strategic_influence(toy, toy_generator, tmp_path):
    from worldagent import experiments
    from worldagent.agents.algorithms import training_config
    from worldagent.agents.distributions import world_distribution
    from worldagent.agents.training import train
    from worldagent.store import RunStore

    generator, dataset_path = toy_generator
    config = training_config(toy, episodes=32)
    distribution = world_distribution(toy.name, "generator", size=64, seed=0)
    result = train(toy, toy.default_algorithm, config, distribution, tmp_path / "agent", progress=False, distribution_spec="generator")
    assert result.episodes >= 32 and (tmp_path / "agent" / "policy").is_dir()

    setup = experiments.setup(toy.name, str(tmp_path / "agent"), generator, repeats=2)
    store = RunStore(tmp_path / "store.sqlite")
    random = experiments.random_evaluation(store, setup, "reward", worlds=8, seed=0, progress=False)
    assert len(random) == 8 and all(math.isfinite(e.score) for e in random)
    found = experiments.strategic_evaluation(store, setup, "reached", budget=8, seed=0, progress=False)
    assert found["metric"] == "reached" and found["min"].score <= found["max"].score
    assert "reached the goal" in found["notes"][0]

    summary = experiments.influence(
        tmp_path / "influence",
        setup,
        toy.selection,
        episodes=32,
        seeds=(0,),
        candidates=16,
        eval_worlds=4,
        progress=False,
    )
    assert summary, "influence returned nothing"


@pytest.mark.example  # its own step in .ci/run with the example env's, outside the default run's 5 minutes
def test_reproduce_tiny_has_a_toy_report_section(toy, tmp_path):
    from worldagent.reproduce.pipeline import reproduce
    from worldagent.reproduce.presets import get_preset

    preset = get_preset("tiny")
    assert toy.name in preset.envs
    lines = []
    reproduce(preset, tmp_path, [toy.name], progress=False, echo=lines.append)
    html = (tmp_path / "report.html").read_text()
    assert f"<h3>{toy.name}</h3>" in html
    values = dict(re.findall(r'data-key="([^"]+)" data-value="([^"]+)"', html))
    numbers = {key: float(value) for key, value in values.items() if key.startswith(f"{toy.name}.")}
    assert numbers, "the report has no toy numbers"
    assert math.isfinite(numbers[f"{toy.name}.random.mean_raw"])
    assert 0.0 <= numbers[f"{toy.name}.random.mean_normalised"] <= 1.0
    atlas = re.search(r'<section id="atlas">(.*?)</section>', html, re.S).group(1)
    # no atlas budget: the phase says so, and where to set one
    assert f"skipped: {toy.name}&#x27;s preset &#x27;tiny&#x27; gives atlas_budget 0" in atlas
    assert "EnvSpec.presets[&#x27;tiny&#x27;][&#x27;atlas_budget&#x27;]" in atlas
    assert any("atlas: done" in line and "set EnvSpec.presets['tiny']['atlas_budget'] to run it" in line for line in lines)
