"""Backends: a campaign on a local Ray cluster fills the same store as one run here, even when a worker dies."""

from __future__ import annotations

import os
import socket
import sys
import time

import pytest
from typer.testing import CliRunner

from worldagent import experiments
from worldagent.cli import app
from worldagent.errors import WorldagentError
from worldagent.evaluation import backends
from worldagent.evaluation.backends import LocalBackend, check_listening, join_cluster, join_failure, make_backend, split
from worldagent.search.campaign import CampaignSpec, run_campaign
from worldagent.search.objectives import LatentObjective, Objective
from worldagent.store import RunStore


def stored(path, name: str) -> list[tuple]:
    """A campaign's evaluations as comparable rows, in (generation, slot) order."""
    with RunStore(path) as store:
        rows = store.iter_evaluations(name, with_worlds=True)
        return sorted((e.generation, e.slot, e.latent.tolist(), e.score, e.episodes, {k: v.tolist() for k, v in e.world.items()}) for e in rows)


def test_batches_split_evenly_or_by_chunk():
    assert split(range(5), 2) == [[0, 1, 2], [3, 4]]
    assert split(range(5), 1) == [[0, 1, 2, 3, 4]]
    assert split(range(5), 2, chunk=2) == [[0, 1], [2, 3], [4]]
    assert split([], 3) == []
    assert isinstance(make_backend("local"), LocalBackend)
    with pytest.raises(WorldagentError, match="unknown backend 'spark'; use one of: local, ray"):
        make_backend("spark")
    with pytest.raises(WorldagentError, match="--ray-address needs --backend ray"):
        make_backend("local", "10.0.0.1:6379")


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_an_address_where_nothing_listens_is_refused_at_once():
    with pytest.raises(WorldagentError, match="nothing answers at 127.0.0.1:.*start a cluster with `ray start --head`"):
        check_listening(f"127.0.0.1:{free_port()}")
    with pytest.raises(WorldagentError, match="is not HOST:PORT"):
        check_listening("my-cluster")
    check_listening(None)  # a new local cluster: nothing to check


def test_a_cluster_that_never_answers_fails_within_the_join_timeout(monkeypatch):
    class SilentRay:  # ray.init against a port that listens but never speaks Ray: it waits for minutes
        def init(self, **kwargs):
            time.sleep(30)

    monkeypatch.setattr(backends, "JOIN_TIMEOUT_S", 0.5)
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        address = f"127.0.0.1:{server.getsockname()[1]}"
        started = time.monotonic()
        with pytest.raises(WorldagentError, match=f"the Ray cluster at {address} did not answer within 0.5 s"):
            join_cluster(SilentRay(), address, None)
        assert time.monotonic() - started < 5


def test_a_missing_token_is_named_as_the_cause():
    logged = (
        "gcs_client.cc:210: Failed to get cluster ID from GCS server: Unauthenticated: RPC error: InvalidAuthToken: Authentication token is missing"
    )
    assert "requires a token; run with RAY_AUTH_MODE=token" in join_failure(ConnectionError("Failed to connect"), logged)
    assert join_failure(ConnectionError("Failed to connect to Ray cluster"), "") == "Failed to connect to Ray cluster; check --ray-address."


class Echo:
    def __call__(self, z, seeds):
        return z


def test_each_evaluator_is_shipped_under_its_own_token_even_when_python_reuses_its_id():
    """Workers cache evaluators by token: a freed evaluator's id() comes back for the next one, and a
    token keyed on it made workers run the previous campaign's evaluator (latents of the wrong shape)."""
    shipper = object.__new__(backends.RayBackend)
    shipper.ray, shipper._shipped = type("FakeRay", (), {"put": staticmethod(lambda value: object())}), None
    tokens = [shipper._ship(Echo())[0] for _ in range(20)]  # each freed at once: CPython hands its id to the next
    assert len(set(tokens)) == 20
    kept = lambda z, s: z  # noqa: E731
    assert shipper._ship(kept) == shipper._ship(kept)  # the same evaluator is shipped once


ray = pytest.importorskip("ray")


@pytest.fixture(scope="module")
def cluster():
    """A local Ray cluster of two workers, shared by this file's tests."""
    backend = make_backend("ray", workers=2)
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # workers cannot import the tests
    yield backend
    ray.shutdown()


class DiesOnce:
    """An evaluator whose worker process dies the first time it runs (a marker file remembers)."""

    def __init__(self, inner, marker):
        self.inner, self.marker = inner, str(marker)

    def __call__(self, z, seeds):
        if not os.path.exists(self.marker):
            open(self.marker, "w").close()
            os._exit(1)  # the worker dies mid-generation, as a killed node would
        return self.inner(z, seeds)


@pytest.mark.integration
def test_a_ray_campaign_fills_the_same_store_as_a_local_one_even_when_a_worker_dies(tmp_path, cluster, racing_generator):
    setup = experiments.setup("racing", "driver", racing_generator, repeats=2)
    objective = LatentObjective(Objective("racing", "return", False), setup.env, setup.policy, setup.generator, 2, setup.params)
    spec = CampaignSpec("c", "racing", "return", False, "cmaes", 42, 3, racing_generator.latent_dim)
    with RunStore(tmp_path / "local") as store:
        run_campaign(store, spec, objective, progress=False)
    with RunStore(tmp_path / "ray") as store:
        found = run_campaign(store, spec, DiesOnce(objective, tmp_path / "died"), progress=False, backend=cluster)
    assert (tmp_path / "died").exists() and len(found) == 42
    assert stored(tmp_path / "ray", "c") == stored(tmp_path / "local", "c")


@pytest.mark.integration
def test_the_search_command_on_ray_matches_local(tmp_path, cluster, racing_vae, racing_data, racing_generator, monkeypatch):
    from worldagent.worlds.generator import save_generator

    monkeypatch.chdir(tmp_path)
    (tmp_path / "drive_mod.py").write_text("import numpy as np\n\ndef act(obs):\n    return np.where(obs[:, 0] > obs[:, 1], 0, 2)\n")
    gen = save_generator(tmp_path / "gen", racing_vae, racing_data.save(tmp_path / "data.npz"), racing_generator)
    common = ["search", "racing", "--agent", "drive_mod:act", "--generator", str(gen), "--budget", "42", "--repeats", "2", "--quiet"]
    runner = CliRunner()
    result = runner.invoke(app, [*common, "--backend", "local", "--out", "local"])
    assert result.exit_code == 0, result.output
    for attempt in range(5):  # Ray's two workers split each generation 11 + 10: a batch-dependent score would show
        result = runner.invoke(app, [*common, "--backend", "ray", "--out", f"ray{attempt}"])
        assert result.exit_code == 0, result.output
        assert stored(tmp_path / f"ray{attempt}", "cmaes-max-return-s0") == stored(tmp_path / "local", "cmaes-max-return-s0"), f"attempt {attempt}"
    with RunStore(tmp_path / "ray0") as store:
        assert store.campaign("cmaes-max-return-s0").config["agent"]["kind"] == "callable"


@pytest.mark.integration
@pytest.mark.slow  # ~16 s of one worker: the default run was 307 s of its 300 with it
def test_many_runs_trained_on_ray_equal_those_trained_here_and_resume_there(tmp_path, cluster):
    """Issue 28: a program's runs as one Ray task give the agents a local many-run gives, resuming a killed run's checkpoints."""
    import jax
    import numpy as np

    from worldagent.agents.distributions import world_distribution
    from worldagent.agents.many import ManyRun, train_many
    from worldagent.agents.ppo import PPOConfig

    config = PPOConfig(total_episodes=8, num_envs=4, num_steps=16, num_minibatches=2, update_epochs=1, hidden=(8,))
    pool = world_distribution("racing", "generator", size=4, seed=0)
    runs = lambda where: [ManyRun(tmp_path / where / f"s{seed}", seed=seed, distribution=pool) for seed in (0, 1)]  # noqa: E731
    here = train_many("racing", "ppo", config, runs("here"), progress=False, chunk_updates=2)
    train_many("racing", "ppo", config, runs("ray"), progress=False, chunk_updates=2, stop_after_chunks=1)  # a killed run's checkpoints
    there = train_many("racing", "ppo", config, runs("ray"), progress=False, chunk_updates=2, backend=cluster)
    for a, b in zip(here, there):
        assert a.episodes == b.episodes >= 8
        for x, y in zip(jax.tree_util.tree_leaves(a.agent.params), jax.tree_util.tree_leaves(b.agent.params)):
            np.testing.assert_array_equal(x, y)


@pytest.mark.integration
def test_a_confirmation_on_ray_stores_the_rows_of_one_made_here(tmp_path, cluster, racing_generator):
    import dataclasses

    from worldagent.analysis.confirm import confirm

    setup = experiments.setup("racing", "driver", racing_generator, repeats=2)
    rows = {}
    for name, backend in (("local", None), ("ray", cluster)):
        with RunStore(tmp_path / name) as store:
            found = experiments.random_evaluation(store, setup, "return", worlds=10, seed=0, progress=False)
            confirm(store, dataclasses.replace(setup, backend=backend), found, name="all", repeats=4, seed=0, progress=False)
            rows[name] = sorted((c.world, c.seed, c.repeats, str(c.episodes)) for c in store.confirmations())
    assert rows["ray"] == rows["local"] and len(rows["local"]) > 1
