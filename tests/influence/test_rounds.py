"""Influence on the toy env: seeds x arms trained as one program, and the phases iterated (``--rounds``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import toy_env
from worldagent.agents import many
from worldagent.agents.ppo import PPOConfig
from worldagent.errors import WorldagentError
from worldagent.experiments import influence, setup
from worldagent.influence.cache import load_influenced_worlds
from worldagent.influence.rounds import merge_worlds, round_campaigns, worlds_file
from worldagent.store import RunStore

TINY = PPOConfig(total_episodes=8, num_envs=4, num_steps=8, num_minibatches=2, update_epochs=1, hidden=(8,))
SELECT = "reached < 0.5"


@pytest.fixture(scope="module")
def toy():
    with toy_env.registered() as spec:
        yield spec


@pytest.fixture(scope="module")
def toy_generator(toy):
    from worldagent.worlds.dataset import make_dataset
    from worldagent.worlds.generator import build_generator
    from worldagent.worlds.vae import VAEConfig, train_vae

    dataset = make_dataset(toy.name, 64, 0, progress=False)
    vae = train_vae(dataset, VAEConfig(encoder=(32,), decoder=(32,), epochs=1, batch_size=32, warmup_epochs=1), progress=False)
    return build_generator(vae, dataset)


def run(run_dir, toy, generator, rounds=2, **kwargs):
    return influence(
        run_dir,
        setup(toy.name, "random", generator, repeats=1),
        SELECT,
        episodes=8,
        seeds=(0, 1),
        candidates=6,
        eval_worlds=3,
        config=TINY,
        progress=False,
        rounds=rounds,
        **kwargs,
    )


def file_times(directory) -> dict:
    return {str(p.relative_to(directory)): p.stat().st_mtime_ns for p in sorted(directory.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def interrupted(tmp_path_factory, toy, toy_generator):
    """Two rounds, killed in round 2's training after one chunk, then rerun: (run dir, what was there at the kill, the result)."""
    run_dir = tmp_path_factory.mktemp("rounds") / "run"
    real, calls = many.train_many, []

    def killed_in_round_2(*args, **kwargs):
        calls.append(len(args[3]))
        if len(calls) == 2:  # round 2's training: one chunk, then the kill
            real(*args, **{**kwargs, "stop_after_chunks": 1})
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    many.train_many = killed_in_round_2
    try:
        with pytest.raises(KeyboardInterrupt):
            run(run_dir, toy, toy_generator, runs_per_program=4)
    finally:
        many.train_many = real
    assert calls == [4, 2]  # round 1: 2 seeds x {default, influenced} in one call; round 2: the 2 influenced agents
    with RunStore(run_dir, create=False) as store:
        counts = {c.name: len(store.evaluations(c.name)) for c in store.campaigns()}
    at_kill = {"round1": file_times(run_dir / "agents"), "counts": counts, "files": file_times(run_dir / "round-2")}
    return run_dir, at_kill, run(run_dir, toy, toy_generator, runs_per_program=4)


@pytest.mark.slow  # ~25 s of CPU: three influence runs of two rounds on the toy
def test_round_2_resumes_at_its_training_chunk_and_keeps_every_round(interrupted):
    run_dir, at_kill, result = interrupted
    assert "round-2/agents/influenced-s0/checkpoint.msgpack" in {f"round-2/{k}" for k in at_kill["files"]}
    assert not any(k.endswith("trained.json") for k in at_kill["files"])  # killed before either finished
    assert file_times(run_dir / "agents") == at_kill["round1"]  # round 1's agents were not touched again
    with RunStore(run_dir, create=False) as store:
        counts = {c.name: len(store.evaluations(c.name)) for c in store.campaigns()}
    with RunStore(run_dir, create=False) as store:
        first = [e.latent.tolist() for e in store.evaluations("influence-candidates")]
        assert all(e.latent.tolist() not in first for e in store.evaluations(round_campaigns(2, 0)[0]))  # fresh candidates
    for seed in (0, 1):
        for name in round_campaigns(2, seed)[:1]:
            assert counts[name] == at_kill["counts"][name] == 6  # round 2's search was not run again
        assert counts[f"influence-eval-round2-influenced-s{seed}-w3-r1"] == 3
        record = json.loads((run_dir / "round-2" / "agents" / f"influenced-s{seed}" / "trained.json").read_text())
        assert record["episodes"] >= 8 and "(round 2)" in record["distribution"]
    [later] = result["rounds"]
    assert later["round"] == 2 and later["dir"] == "round-2"
    on_disk = json.loads((run_dir / "round-2" / "influence.json").read_text())
    assert on_disk["summary"] == later["summary"] and on_disk["round"] == 2
    assert on_disk["per_seed"]["default"] == result["per_seed"]["default"]  # round 1's default agents
    assert json.loads((run_dir / "influence.json").read_text())["rounds"][0]["summary"] == later["summary"]


@pytest.mark.slow  # ~25 s of CPU: three influence runs of two rounds on the toy
def test_a_round_adds_the_worlds_its_agent_fails_on_to_the_previous_ones(interrupted, toy):
    run_dir, _, result = interrupted
    first, _, _ = load_influenced_worlds(run_dir, toy.name)
    for seed in ("0", "1"):
        worlds, latents, values = load_influenced_worlds(run_dir / "round-2", toy.name, worlds_file(int(seed)))
        grown = result["rounds"][0]["worlds"]
        assert len(latents) == grown["training_worlds"][seed] == len(first.walls) + grown["added"][seed]
        assert grown["added"][seed] <= grown["selected"][seed]
        np.testing.assert_array_equal(np.asarray(worlds.walls)[: len(first.walls)], np.asarray(first.walls))  # round 1's stay, first
        assert np.all(values["reached"] < 0.5)


@pytest.mark.slow  # ~25 s of CPU: three influence runs of two rounds on the toy
def test_a_rerun_of_a_finished_run_trains_and_evaluates_nothing_new(interrupted, toy, toy_generator):
    run_dir, _, result = interrupted
    before = file_times(run_dir)
    calls = []
    real = many.train_many
    many.train_many = lambda *a, **k: calls.append(a) or real(*a, **k)
    try:
        again = run(run_dir, toy, toy_generator, runs_per_program=4)
    finally:
        many.train_many = real
    assert calls == [] and again["rounds"][0]["summary"] == result["rounds"][0]["summary"]
    assert {k: v for k, v in file_times(run_dir).items() if "agents" in k} == {k: v for k, v in before.items() if "agents" in k}


def test_merging_keeps_each_world_once_in_order(toy):
    worlds = toy.generate(np.array([5, 6, 7]))  # three distinct procedural grids
    pick = lambda i: toy.world_from_arrays({k: v[i] for k, v in toy.world_to_arrays(worlds).items()})  # noqa: E731
    old = (pick([0, 1]), np.array([[0.0], [1.0]]), {"reached": np.array([0.0, 0.1])})
    new = (pick([1, 2, 2]), np.array([[1.5], [2.0], [2.5]]), {"reached": np.array([0.2, 0.3, 0.4])})
    merged, latents, values = merge_worlds(toy, old, new)
    assert latents.tolist() == [[0.0], [1.0], [2.0]] and values["reached"].tolist() == [0.0, 0.1, 0.3]
    np.testing.assert_array_equal(np.asarray(merged.walls), np.asarray(worlds.walls))
    assert merge_worlds(toy, old, None) is old


def test_bad_rounds_and_runs_per_program_are_refused(tmp_path, toy):
    from worldagent.influence.experiment import influence as run_influence

    # refused before the env, agent or generator is touched (None here)
    with pytest.raises(WorldagentError, match=r"rounds=0; pass 1 .*--rounds"):
        run_influence(tmp_path, toy, None, None, None, None, SELECT, episodes=8, rounds=0)
    with pytest.raises(WorldagentError, match=r"runs_per_program=0; .*--runs-per-program"):
        run_influence(tmp_path, toy, None, None, None, None, SELECT, episodes=8, runs_per_program=0)
    assert not (tmp_path / "store.sqlite").exists()
