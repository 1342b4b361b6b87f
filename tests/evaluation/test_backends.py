"""Backends: a campaign on a local Ray cluster fills the same store as one run here, even when a worker dies."""

from __future__ import annotations

import os
import sys

import pytest
from typer.testing import CliRunner

from worldagent import experiments
from worldagent.cli import app
from worldagent.errors import WorldagentError
from worldagent.evaluation.backends import LocalBackend, make_backend, split
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


def test_the_search_command_on_ray_matches_local(tmp_path, cluster, racing_vae, racing_data, racing_generator, monkeypatch):
    from worldagent.worlds.generator import save_generator

    monkeypatch.chdir(tmp_path)
    (tmp_path / "drive_mod.py").write_text("import numpy as np\n\ndef act(obs):\n    return np.where(obs[:, 0] > obs[:, 1], 0, 2)\n")
    gen = save_generator(tmp_path / "gen", racing_vae, racing_data.save(tmp_path / "data.npz"), racing_generator)
    common = ["search", "racing", "--agent", "drive_mod:act", "--generator", str(gen), "--budget", "42", "--repeats", "2", "--quiet"]
    runner = CliRunner()
    for backend in ("local", "ray"):
        result = runner.invoke(app, [*common, "--backend", backend, "--out", backend])
        assert result.exit_code == 0, result.output
    assert stored(tmp_path / "ray", "cmaes-max-return-s0") == stored(tmp_path / "local", "cmaes-max-return-s0")
    with RunStore(tmp_path / "ray") as store:
        assert store.campaign("cmaes-max-return-s0").config["agent"]["kind"] == "callable"
