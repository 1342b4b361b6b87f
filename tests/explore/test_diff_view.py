"""The explorer over a ``worldagent diff --out``: the regressed worlds, and both agents ready to play side by side."""

from __future__ import annotations

import json

import numpy as np
import pytest
from fastapi.testclient import TestClient

from worldagent import differential
from worldagent.commands.explore import open_run
from worldagent.explore.server import make_app
from worldagent.explore.session import Session
from worldagent.store import RunStore

LOCAL = "http://127.0.0.1"
CAMPAIGN = "diff-campaign-random-return-s0-s0"


@pytest.fixture(scope="module")
def diff_run(toy_spec, toy_run, tmp_path_factory):
    """A diff directory: the toy's homing agent (A) against its random one (B) on the 24 worlds of the run's random campaign."""
    out = tmp_path_factory.mktemp("diff")
    generator = toy_run / toy_spec.name / "generator"
    setup = differential.diff_setup(toy_spec.name, "scripted/homing", "scripted/random", generator, repeats=2)
    worlds = differential.campaign_worlds(toy_spec, toy_run / toy_spec.name, "random-return-s0")
    with RunStore(out) as store:
        result = differential.diff(store, setup, worlds=worlds, progress=False)
    (out / "diff.json").write_text(json.dumps({**result, "generator": str(generator)}))
    return out, result


def test_a_diff_directory_opens_with_its_two_agents_and_its_regressed_worlds(toy_spec, diff_run):
    out, result = diff_run
    session = Session.of(open_run(out, None, None, "", ""))
    info, toy = session.describe()["envs"][0], session.env(toy_spec.name)
    assert info["diffs"] == [CAMPAIGN] and {"diff/A", "diff/B"} <= set(info["agents"])
    client = TestClient(make_app(session), base_url=LOCAL)
    found = client.get(f"/api/{toy_spec.name}/diff").json()
    failure = result["worlds"]["failure"]
    assert (found["regressed"], found["improved"], found["worlds"]) == (failure["regressed"], failure["improved"], 24)
    assert found["regressed"] > 0 and found["agents"] == ["diff/A", "diff/B"] and found["event"] == "reached < 0.5"
    priors = [row["log_prior"] for row in found["rows"]]
    assert priors == sorted(priors, reverse=True) and len(found["rows"]) == found["regressed"]
    for row in found["rows"]:
        assert row["b"]["reached"] < 0.5 <= row["a"]["reached"]
        near = row["nearest_passing"]
        assert near is not None and near != row["index"] and toy.means["reached"][near] >= 0.5  # B's metrics under their names
    # the World view plays both agents on a regressed world: B fails there with its episodes' keys, A passes
    row = found["rows"][0]
    stored = toy.evaluations[row["index"]]
    assert np.mean([e["reached"] for e in stored.episodes]) < 0.5 <= np.mean([e["A.reached"] for e in stored.episodes])
    assert row["replay"]["episodes"] == len(stored.episodes) == 2
    for agent, prefix in zip(found["agents"], ("A.", "")):
        request = {"world": row["index"], "agent": agent, **row["replay"], "size": 64}  # the keys the diff scored the world with
        played = client.post(f"/api/{toy_spec.name}/play", json=request)
        assert played.status_code == 200 and played.json()["agent"] == agent
        assert played.json()["means"]["reached"] == pytest.approx(np.mean([e[prefix + "reached"] for e in stored.episodes]))
    assert all(r["nearest_replay"]["episodes"] == 2 for r in found["rows"])
    bad = client.get(f"/api/{toy_spec.name}/diff", params={"campaign": "nope"})
    assert bad.status_code == 400 and f"diff campaigns of toy: {CAMPAIGN}" in bad.json()["error"]


def test_a_run_without_a_diff_says_so(session):
    client = TestClient(make_app(session), base_url=LOCAL)
    assert session.describe()["envs"][0]["diffs"] == []
    refused = client.get("/api/toy/diff")
    assert refused.status_code == 400 and "holds no diff campaign" in refused.json()["error"]
