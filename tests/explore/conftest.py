"""A tiny run directory of the toy gridworld, written by hand in a few seconds, for the explorer's tests.

It holds what ``reproduce`` would leave: a manifest naming the env, a dataset and a generator
(an untrained VAE: its repair still makes every G(z) a valid world; training would cost seconds), and a store with a random campaign (some worlds failing:
``reached < 0.5``) and an atlas campaign over the toy's descriptors. No trained agent: the
explorer plays the toy's scripted ones.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json

import jax
import numpy as np
import pytest

from worldagent.envs import registry
from worldagent.runs import RunLayout

WORLDS = 24  # stored evaluations per campaign
ATLAS_CELLS = (3, 3)


def cell_centres(positions, world, size: int):
    """The toy's (row, col) cells as pixel (x, y) centres on its picture (what a spec's ``locate`` gives)."""
    side = np.shape(world.walls)[-1]
    cells = np.asarray(positions, np.float64)
    return np.stack([(cells[..., 1] + 0.5) * size / side, (cells[..., 0] + 0.5) * size / side], axis=-1)


def goal_mark(env, state):
    """The toy's goal cell, shown until the agent reaches it (what a spec's ``marks`` gives: harvest's apples)."""
    import jax.numpy as jnp

    side = state.world.goal.shape[-1]
    index = jnp.argmax(jnp.ravel(state.world.goal))
    return {"goal": (jnp.stack([index // side, index % side]).astype(jnp.int32)[None], ~jnp.reshape(state.reached, (1,)))}


GOAL_STYLE = {"goal": {"shape": "dot", "colour": "#ff00ff", "radius": 0.06}}


def explorer_toy(name: str = "toy"):
    """The toy env's spec with a picture locator, marks and a failure event (what the explorer's views use);
    another ``name`` gives a second environment of a run."""
    import toy_env

    pictures = dataclasses.replace(toy_env.SPEC.pictures, locate=cell_centres, marks=goal_mark, mark_styles=GOAL_STYLE)
    return dataclasses.replace(toy_env.SPEC, name=name, pictures=pictures, failure="reached < 0.5")


@contextlib.contextmanager
def registered(spec):
    """``spec`` registered while the block runs; whatever had its name before comes back after
    (other test files on this worker see the toy as they expect)."""
    before = registry.get(spec.name) if spec.name in registry.names() else None
    registry.register(spec, replace=True)
    try:
        yield spec
    finally:
        registry.unregister(spec.name) if before is None else registry.register(before, replace=True)


@pytest.fixture(scope="module")
def toy_spec():
    """The explorer's toy, registered for one test file."""
    with registered(explorer_toy()) as spec:
        yield spec


def fake_episodes(rng, failing: bool) -> list[dict]:
    """4 episodes' metrics; a failing world reaches the goal in at most one of them."""
    reached = rng.random(4) < (0.2 if failing else 0.9)
    return [{"return": float(9.0 * r - 0.3 * s), "reached": float(r), "steps": float(s)} for r, s in zip(reached, rng.integers(3, 30, 4))]


def store_campaign(store, spec, dataset, name: str, config: dict, latents: np.ndarray, rng) -> None:
    campaign = store.open_campaign(name, spec.name, "return", False, "random", len(latents), 0, config, resume=False)
    for slot, z in enumerate(latents):
        world = dataset.world(slot % len(dataset))
        episodes = fake_episodes(rng, failing=slot % 3 == 0)
        store.add(campaign, 0, slot, z, float(np.mean([e["return"] for e in episodes])), episodes, 0.0, world=world)


@pytest.fixture(scope="session")
def toy_run(tmp_path_factory):
    """The run directory (see the module docstring), built once per worker."""
    with registered(explorer_toy()) as spec:
        return write_toy_run(spec, tmp_path_factory.mktemp("explore") / "run")


def write_toy_run(toy_spec, run_dir):
    write_toy_env(toy_spec, run_dir)
    write_manifest(run_dir, [toy_spec.name])
    return run_dir


def write_manifest(run_dir, envs: list[str]) -> None:
    done = {"status": "done", "config": {}, "outputs": {}}
    manifest = {"format_version": 1, "preset": "test", "seed": 0, "envs": envs, "phases": {f"{env}/generator": done for env in envs}}
    (run_dir / "manifest.json").write_text(json.dumps(manifest))


def write_toy_env(toy_spec, run_dir):
    """One environment's part of the toy run: dataset, generator, and a store of a random and an atlas campaign."""
    from worldagent.search.atlas import Grid
    from worldagent.store import RunStore
    from worldagent.worlds.dataset import make_dataset
    from worldagent.worlds.generator import build_generator, save_generator
    from worldagent.worlds.vae import TrainedVAE, VAEConfig, make_vae

    layout = RunLayout(run_dir, toy_spec.name)
    dataset = make_dataset(toy_spec.name, 64, 0, progress=False)
    layout.dir.mkdir(parents=True)
    dataset.save(layout.dataset_path)
    config = VAEConfig(encoder=(16,), decoder=(16,), latent_dim=3)
    model = make_vae(toy_spec.cell_count, config)
    shapes = jax.eval_shape(model.init, jax.random.key(0), np.zeros((1, toy_spec.cell_count), np.float32), jax.random.key(1))["params"]
    weights = np.random.default_rng(1)  # random weights of the right shapes: tracing is enough, no init to compile
    params = jax.tree_util.tree_map(lambda leaf: weights.normal(0.0, 0.5, leaf.shape).astype(leaf.dtype), shapes)
    vae = TrainedVAE(model, params, config, toy_spec.name, toy_spec.cell_shape, dataset.fingerprint, [], np.zeros(0, np.int64))
    save_generator(layout.generator_dir, vae, layout.dataset_path, build_generator(vae, dataset))
    rng = np.random.default_rng(0)
    grid = Grid(toy_spec.metrics.default_descriptors, ATLAS_CELLS, ((0.0, 0.5), (0.0, 12.0)))
    with RunStore(layout.store_path) as store:
        store_campaign(store, toy_spec, dataset, "random-return-s0", {}, rng.normal(size=(WORLDS, 3)), rng)
        store_campaign(store, toy_spec, dataset, "atlas-min-return-s0", {"atlas": {"grid": grid.record()}}, rng.normal(size=(WORLDS, 3)), rng)
    return layout


@pytest.fixture
def fresh_toy_run(toy_spec, tmp_path):
    """A toy run of this test's own, to change (the shared ``toy_run`` stays as built)."""
    return write_toy_run(toy_spec, tmp_path / "run")


@pytest.fixture(scope="module")
def session(toy_spec, toy_run):
    """The explorer's ``Session`` over the toy run (its generator and agents load on first use)."""
    from worldagent.explore.session import Session

    return Session.open(toy_run)


DIFF_PAIRS = {  # diff campaign -> (A, B) scripted agents, and every how many worlds B fails where A passes
    "diff-homing-random-s0": (("homing", "random"), 2),
    "diff-homing-random-s1": (("homing", "random"), 3),
}


def store_diff_campaign(store, spec, dataset, name: str, agents: tuple[str, str], every: int, latents: np.ndarray, rng) -> None:
    """A diff campaign as ``differential.fixed_set`` stores one: the pair in ``config["diff"]``, B's metrics under their
    names and A's under ``A.<name>`` (A passes everywhere; B fails on every ``every``-th world). No episode is played."""
    from worldagent.search.campaign import campaign_stream

    records = {side: {"kind": "scripted", "path": agent, "sha256": None} for side, agent in zip("ab", agents)}
    config = {"dim": latents.shape[1], "diff": records, "stream": campaign_stream(name)}
    campaign = store.open_campaign(name, spec.name, "return", False, "fixed", len(latents), 0, config, resume=False)
    for slot, z in enumerate(latents):
        b = fake_episodes(rng, failing=slot % every == 0)
        episodes = [{**e, **{f"A.{k}": v for k, v in passing.items()}} for e, passing in zip(b, fake_episodes(rng, failing=False))]
        for e in episodes:
            e["A.reached"] = 1.0  # A passes every world: the regressed worlds are B's failures
        store.add(campaign, 0, slot, z, float(np.mean([e["return"] for e in episodes])), episodes, 0.0, world=dataset.world(slot % len(dataset)))


def add_diff_campaigns(spec, run_dir, campaigns: dict = DIFF_PAIRS, seed: int = 1) -> None:
    """Write ``campaigns`` (as ``DIFF_PAIRS``) into the toy env's store of ``run_dir``, as `worldagent diff` would."""
    from worldagent.store import RunStore
    from worldagent.worlds.dataset import WorldDataset

    layout = RunLayout(run_dir, spec.name)
    dataset, rng = WorldDataset.load(layout.dataset_path), np.random.default_rng(seed)
    with RunStore(layout.store_path) as store:
        for name, (agents, every) in campaigns.items():
            store_diff_campaign(store, spec, dataset, name, agents, every, rng.normal(size=(WORLDS, 3)), rng)


@pytest.fixture(scope="session")
def diff_toy_run(tmp_path_factory):
    """A run of two environments: ``toy`` with two diff campaigns (``DIFF_PAIRS``), ``toy2`` without any."""
    run_dir = tmp_path_factory.mktemp("explore-diff") / "run"
    with registered(explorer_toy()) as toy, registered(explorer_toy("toy2")) as toy2:
        write_toy_env(toy, run_dir)
        write_toy_env(toy2, run_dir)
        add_diff_campaigns(toy, run_dir)
    write_manifest(run_dir, ["toy", "toy2"])
    return run_dir


@pytest.fixture(scope="module")
def toy2_spec():
    """A second toy environment (``toy2``), registered for one test file."""
    with registered(explorer_toy("toy2")) as spec:
        yield spec


@pytest.fixture
def add_diff():
    """``add_diff_campaigns``: write diff campaigns into a toy run (as `worldagent diff` would), for a test to call."""
    return add_diff_campaigns
