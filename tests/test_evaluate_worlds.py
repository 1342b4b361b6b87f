"""``worldagent evaluate worlds ENV --worlds FILE.npz|NAME`` (issue 42, item 1): agents scored on given worlds (a dataset
file, explorer exports, a named set an ``EnvSpec`` declares) into the run store, as every campaign."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest
from typer.testing import CliRunner

import toy_env
from worldagent.cli import app
from worldagent.envs import registry
from worldagent.search.campaign import evaluation_seed
from worldagent.store import RunStore

runner = CliRunner()
AGENT = "homing"  # the toy's scripted policy: no training, and it reaches some goals and not others
SET = "pair"  # the named set the toy variant of these tests declares


def corner_pair():
    """Two toy worlds: the goal beside the start (reached at once), and a goal walled off (never reached)."""
    walls = np.zeros((2, 7, 7), bool)
    goal = np.zeros((2, 7, 7), bool)
    goal[0, 0, 1] = True
    goal[1, 6, 6] = True
    walls[1, 5, 6] = walls[1, 6, 5] = walls[1, 5, 5] = True
    return toy_env.SPEC.world_type(walls=walls, goal=goal)


@pytest.fixture(scope="module")
def toy():
    """The toy, with a named world set, registered for this module."""
    spec = registry.register(dataclasses.replace(toy_env.SPEC, world_sets={SET: corner_pair}))
    try:
        yield spec
    finally:
        registry.unregister(spec.name)


@pytest.fixture(scope="module")
def dataset_file(toy, tmp_path_factory):
    from worldagent.worlds.dataset import make_dataset

    path = tmp_path_factory.mktemp("worlds") / "held-out.npz"
    make_dataset(toy.name, 5, 100, progress=False).save(path)
    return path


@pytest.fixture(scope="module")
def generator_dir(toy, dataset_file, tmp_path_factory):
    """A toy generator (one epoch of a small VAE: only its encoder's placement is used)."""
    from worldagent.worlds.dataset import WorldDataset
    from worldagent.worlds.generator import build_generator, save_generator
    from worldagent.worlds.vae import VAEConfig, train_vae

    dataset = WorldDataset.load(dataset_file)
    vae = train_vae(dataset, VAEConfig(encoder=(16,), decoder=(16,), epochs=1, batch_size=2, warmup_epochs=0), progress=False)
    return save_generator(tmp_path_factory.mktemp("gen") / "generator", vae, dataset_file, build_generator(vae, dataset))


def evaluate(*arguments: str):
    return runner.invoke(app, ["evaluate", "worlds", "toy", "--agent", AGENT, "--repeats", "2", "--quiet", *arguments])


def campaign_of(out):
    with RunStore(out / "store.sqlite", create=False) as store:
        (campaign,) = store.campaigns()
        return campaign, sorted(store.evaluations(campaign.name, with_worlds=True), key=lambda e: e.slot)


def test_a_dataset_file_is_scored_world_by_world_into_the_store_and_a_rerun_resumes(toy, dataset_file, tmp_path):
    from worldagent.agents.loaders import load_agent
    from worldagent.evaluation.local import evaluate as play

    out = tmp_path / "run"
    result = evaluate("--worlds", str(dataset_file), "--out", str(out))
    assert result.exit_code == 0, result.output
    campaign, found = campaign_of(out)
    assert campaign.name.startswith("worlds-held-out-") and campaign.name.endswith("-return-s0") and campaign.optimiser == "given"
    assert [e.slot for e in found] == list(range(5)) and all(len(e.latent) == 0 for e in found)
    worlds = toy.generate(np.arange(100, 105))
    assert all(np.array_equal(e.world["goal"], np.asarray(worlds.goal)[i]) for i, e in enumerate(found))  # each world stored as given
    # world i is played with the keys of (seed 0, generation 0, slot i), as a campaign's slot is
    env, params = toy.make_env()
    keys = jax.numpy.stack([jax.random.split(jax.random.key(evaluation_seed(0, 0, i)), 2) for i in range(5)])
    expected = play(env, load_agent(toy, AGENT), worlds, 2, None, params, keys=keys)["return"].mean(axis=1)
    np.testing.assert_allclose([e.score for e in found], expected, rtol=1e-6)
    assert "held-out.npz[0] (seed 100)" in result.output and "stored in" in result.output and "without latents" in result.output
    assert (out / f"{campaign.name}.png").is_file()
    again = evaluate("--worlds", str(dataset_file), "--out", str(out))
    assert again.exit_code == 0, again.output
    assert [e.finished for e in campaign_of(out)[1]] == [e.finished for e in found]  # nothing evaluated twice


def test_a_named_set_of_the_env_and_explorer_exports(toy, dataset_file, tmp_path):
    from worldagent.worlds.dataset import WorldDataset

    named = evaluate("--worlds", SET, "--out", str(tmp_path / "named"))
    assert named.exit_code == 0, named.output
    campaign, found = campaign_of(tmp_path / "named")
    assert campaign.name == "worlds-pair-return-s0" and campaign.config["worlds"]["count"] == 2
    assert found[0].score > found[1].score  # the goal beside the start is reached, the walled-off one never
    assert "pair[0]: return" in named.output and "pair[1]: return" in named.output
    # two one-world files, as the explorer exports them (seed -1: not generated), evaluated in order
    data = WorldDataset.load(dataset_file)
    exports = []
    for index in (3, 1):
        path = tmp_path / f"toy-world-{index}.npz"
        one = data.subset([index])
        WorldDataset(one.env, np.array([-1]), one.worlds, one.cells, one.cell_shape).save(path)
        exports.append(path)
    both = evaluate("--worlds", str(exports[0]), "--worlds", str(exports[1]), "--out", str(tmp_path / "exports"))
    assert both.exit_code == 0, both.output
    campaign, found = campaign_of(tmp_path / "exports")
    assert campaign.name.startswith("worlds-toy-world-3+1-")
    assert [np.array_equal(e.world["walls"], data.world(i).walls) for e, i in zip(found, (3, 1))] == [True, True]
    assert "toy-world-3.npz[0]: return" in both.output and "(seed" not in both.output


def test_a_generator_places_the_worlds_on_the_explorers_map(toy, dataset_file, generator_dir, tmp_path):
    from worldagent.explore.session import Session
    from worldagent.runs import Run
    from worldagent.worlds.dataset import WorldDataset
    from worldagent.worlds.generator import load_generator

    out = tmp_path / "placed"
    result = evaluate("--worlds", str(dataset_file), "--generator", str(generator_dir), "--out", str(out))
    assert result.exit_code == 0, result.output
    campaign, found = campaign_of(out)
    generator = load_generator(generator_dir)[0]
    means = np.asarray(generator.encode(WorldDataset.load(dataset_file).cells))
    np.testing.assert_allclose(np.stack([e.latent for e in found]), means, rtol=1e-5, atol=1e-6)
    assert campaign.config["latents"] == "encoder means" and "worldagent explore --store" in result.output
    session = Session.of(Run.of_parts(out / "store.sqlite", generator_dir, AGENT)).envs[toy.name]
    assert len(session.evaluations) == 5 and session.map_data()["campaigns"] == [campaign.name]
    # the same worlds without the generator would store them otherwise: refused, with the fix
    refused = evaluate("--worlds", str(dataset_file), "--out", str(out))
    assert refused.exit_code == 2 and "placed its worlds with a generator's encoder" in refused.output


@pytest.mark.parametrize(
    "worlds, message",
    [
        (["mazes"], "neither a .npz file nor a named world set of toy (its sets: pair)"),
        (["no/such/file.npz"], "does not exist"),
        (["pair", "DATASET"], "mixes files with 'pair'"),
        (["pair", "pair"], "one named set at a time"),
    ],
)
def test_bad_worlds_are_refused_in_one_line(toy, dataset_file, tmp_path, worlds, message):
    arguments = [a for w in worlds for a in ("--worlds", str(dataset_file) if w == "DATASET" else w)]
    result = evaluate(*arguments, "--out", str(tmp_path / "bad"))
    assert result.exit_code == 2 and message in result.output and "Traceback" not in result.output, result.output


def test_a_dataset_of_another_env_is_refused(toy, tmp_path):
    from worldagent.worlds.dataset import make_dataset

    path = make_dataset("racing", 2, 0, progress=False).save(tmp_path / "racing.npz")
    result = evaluate("--worlds", str(path), "--out", str(tmp_path / "bad"))
    assert result.exit_code == 2 and "holds racing worlds, not toy worlds" in result.output, result.output


def test_envs_lists_the_named_world_sets(toy):
    result = runner.invoke(app, ["envs"])
    assert result.exit_code == 0 and "world sets:  pair (for evaluate worlds --worlds NAME)" in result.output
    blocks = result.output.split("\n\n")
    for name in ("racing", "harvest"):  # they declare none, so their entries have no such line
        (block,) = [b for b in blocks if b.lstrip().startswith(f"{name}:")]
        assert "world sets:" not in block
