"""The explorer's API over a tiny toy run: every view's numbers, exports, and refusals as one-line JSON."""

from __future__ import annotations

import hashlib
import io

import numpy as np
import pytest
from fastapi.testclient import TestClient

from worldagent.explore.server import make_app
from worldagent.explore.session import jax_row
from worldagent.store import RunStore, world_digest
from worldagent.worlds.dataset import WorldDataset

LOCAL = "http://127.0.0.1"


@pytest.fixture(scope="module")
def client(session):
    return TestClient(make_app(session), base_url=LOCAL)


def stored(toy_run, campaign=None):
    with RunStore(toy_run / "toy" / "store.sqlite", create=False) as store:
        return store.evaluations(campaign, with_worlds=True)


def file_hashes(folder) -> dict:
    """sha256 of every file but SQLite's -wal/-shm (opening a store in WAL mode makes them; its data stays)."""
    return {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.rglob("*")) if p.is_file() and not p.name.endswith(("-wal", "-shm"))}


def test_the_page_and_its_assets_are_served(client):
    page = client.get("/")
    assert page.status_code == 200 and "/static/explorer.js" in page.text
    assert client.get("/static/explorer.js").status_code == 200
    assert client.get("/static/explorer.css").headers["content-type"].startswith("text/css")


@pytest.mark.parametrize(
    "path",
    [
        "/static/..%2f..%2f..%2fpyproject.toml",
        "/static/%2e%2e%2fserver.py",
        "/static/../server.py",
        "/static/..\\server.py",
        "/api/toy/world/..%2f..%2fmanifest.json",
        "/api/..%2f..%2fetc%2fpasswd/map",
        "/runs/manifest.json",
    ],
)
def test_paths_outside_the_assets_are_not_served(client, path):
    response = client.get(path)
    assert 400 <= response.status_code < 500
    assert set(response.json()) == {"error"}


def test_the_run_says_what_each_view_can_show(client):
    (env,) = client.get("/api/run").json()["envs"]
    assert env["name"] == "toy" and env["latent_dim"] == 3 and env["worlds"] == 48
    assert env["metrics"] == ["return", "reached", "steps"] and env["main"] == "return"
    assert env["agents"] == ["scripted/random", "scripted/homing"]  # no trained agent in this run
    assert env["atlases"] == ["atlas-min-return-s0"] and env["animates"] and env["failure"] == "reached < 0.5"


def test_the_run_says_what_each_metric_means_and_each_campaign_is(client, toy_spec):
    (env,) = client.get("/api/run").json()["envs"]
    # the spec's meanings of the metrics shown (the toy says nothing of "steps": no entry rather than an empty one)
    assert env["meanings"] == dict(toy_spec.metrics.meanings) and set(env["meanings"]) == {"return", "reached"}
    assert env["campaign_words"] == {
        "random-return-s0": "Random worlds G(z) scored on return, 24 worlds, seed 0",
        "atlas-min-return-s0": "Atlas (CMA-ME) minimising return over wall_share × goal_distance, 24 evaluations, seed 0",
    }


def test_the_map_places_every_stored_world_by_its_latent(client, toy_run):
    found = client.get("/api/toy/map").json()
    evaluations = stored(toy_run)
    assert found["campaigns"] == ["random-return-s0", "atlas-min-return-s0"]
    latents = np.stack([e.latent for e in evaluations])
    expected = (latents - np.asarray(found["centre"])) @ np.asarray(found["axes"]).T
    np.testing.assert_allclose(np.stack([found["x"], found["y"]], axis=1), expected, atol=1e-3)
    assert np.var(found["x"]) >= np.var(found["y"])  # the first principal axis spreads the most
    means = [np.mean([ep["reached"] for ep in e.episodes]) for e in evaluations]
    np.testing.assert_allclose(found["metrics"]["reached"], means, atol=1e-4)


def test_a_stored_world_and_its_picture(client, toy_run):
    first = stored(toy_run)[5]
    info = client.get("/api/toy/world/5").json()
    assert (info["campaign"], info["slot"]) == (first.campaign, first.slot)
    np.testing.assert_allclose(info["latent"], first.latent, atol=1e-5)
    picture = client.get("/api/toy/world/5.png?size=64")
    assert picture.headers["content-type"] == "image/png" and picture.content[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_latent_decodes_to_a_picture(client, session):
    picture = client.get("/api/toy/decode.png?z=0.5,-1,2&size=96")
    assert picture.status_code == 200 and picture.content[:4] == b"\x89PNG"
    expected = session.envs["toy"].picture(session.envs["toy"].decode([0.5, -1, 2]), 96)
    assert picture.content == expected


def test_play_returns_each_episode_on_the_picture(client):
    request = {"world": 3, "agent": "scripted/homing", "episodes": 3, "seed": 7, "size": 70}
    played = client.post("/api/toy/play", json=request).json()
    assert len(played["episodes"]) == 3 and played["agent"] == "scripted/homing"
    for episode in played["episodes"]:
        path = np.asarray(episode["path"])
        assert path.shape == (episode["steps"] + 1, 1, 2)
        assert ((path >= 0) & (path <= 70)).all()
        np.testing.assert_allclose(path[0, 0], [5.0, 5.0])  # the start cell (0, 0), 10 px per cell
    assert played == client.post("/api/toy/play", json=request).json()  # the same seed plays the same episodes
    latent = client.post("/api/toy/play", json={"z": [0, 0, 0], "agent": "scripted/random", "episodes": 1}).json()
    assert latent["z"] == [0, 0, 0] and set(latent["means"]) >= {"return", "reached", "steps"}


def test_play_carries_the_marks_step_by_step(client, toy_run):
    """The toy's one mark, its goal, is there from the start and vanishes at the step the agent reaches it."""
    played = client.post("/api/toy/play", json={"world": 2, "agent": "scripted/random", "episodes": 4, "seed": 2, "size": 70}).json()
    assert played["marks"] == {"goal": {"shape": "dot", "colour": "#ff00ff", "radius": 4.2, "label": "goal"}}  # 0.06 of 70 px; no label: its kind
    goal = np.argwhere(stored(toy_run)[2].world["goal"])[0]
    at = [(goal[1] + 0.5) * 10, (goal[0] + 0.5) * 10]
    for episode in played["episodes"]:
        changes = episode["marks"]["goal"]
        assert changes[0] == [0, [at], []]
        if episode["metrics"]["reached"]:
            assert changes[1:] == [[episode["steps"], [], [at]]]  # reached at the last step
        else:
            assert changes[1:] == []
    assert 0 < sum(e["metrics"]["reached"] for e in played["episodes"]) < 4  # some episodes reach it, some do not


def test_failures_rank_by_prior_likelihood_and_severity(client, toy_run):
    evaluations = stored(toy_run)
    reached = np.array([np.mean([e["reached"] for e in ev.episodes]) for ev in evaluations])
    latents = np.stack([ev.latent for ev in evaluations])
    digests = np.array([world_digest(ev.world) for ev in evaluations])
    found = client.get("/api/toy/failures?limit=500").json()
    assert found["failing"] == int((reached < 0.5).sum()) == sum(row["evaluations"] for row in found["rows"])
    priors = [row["log_prior"] for row in found["rows"]]
    assert priors == sorted(priors, reverse=True)
    np.testing.assert_allclose(priors[0], -0.5 * (latents[found["rows"][0]["index"]] ** 2).sum() - 1.5 * np.log(2 * np.pi))
    passing = np.flatnonzero(reached >= 0.5)
    for row in found["rows"]:
        others = passing[digests[passing] != digests[row["index"]]]  # the nearest passing world is another world
        distances = np.linalg.norm(latents[others] - latents[row["index"]], axis=1)
        assert row["nearest_passing"] == others[np.argmin(distances)]
    severe = client.get("/api/toy/failures?by=severity&limit=500").json()["rows"]
    worst = {}  # each failing world's most severe evaluation
    for i in np.flatnonzero(reached < 0.5):
        worst[digests[i]] = max(worst.get(digests[i], -np.inf), 0.5 - reached[i])
    assert [r["severity"] for r in severe] == sorted(worst.values(), reverse=True)
    other = client.get("/api/toy/failures", params={"event": "steps > 20"}).json()
    assert other["failing"] == int((np.array([np.mean([e["steps"] for e in ev.episodes]) for ev in evaluations]) > 20).sum())


def test_failures_count_distinct_repaired_worlds_not_latents(client, toy_run):
    evaluations = stored(toy_run)
    failing = [ev for ev in evaluations if np.mean([e["reached"] for e in ev.episodes]) < 0.5]
    digests = [world_digest(ev.world) for ev in failing]
    found = client.get("/api/toy/failures?limit=500").json()
    # the toy run's two campaigns store the same dataset worlds at different latents: fewer worlds than latents
    assert len({tuple(ev.latent) for ev in failing}) == len(failing) > len(set(digests))
    assert found["distinct"] == len(set(digests)) == len(found["rows"])
    by_world = {d: digests.count(d) for d in digests}
    rows = {world_digest(evaluations[row["index"]].world): row["evaluations"] for row in found["rows"]}
    assert rows == by_world
    assert len(client.get("/api/toy/failures?limit=2").json()["rows"]) == 2
    assert client.get("/api/toy/failures?limit=2").json()["distinct"] == found["distinct"]  # the count is of all, not of the rows shown


def test_worlds_stored_without_arrays_are_told_apart_by_their_decoded_world(toy_spec, fresh_toy_run):
    from worldagent.explore.session import Session
    from worldagent.search.objectives import generate
    from worldagent.worlds.generator import load_generator

    run_dir = fresh_toy_run
    store_path = run_dir / "toy" / "store.sqlite"
    (z,) = [ev.latent for ev in stored(run_dir, "random-return-s0")[:1]]
    with RunStore(store_path) as store:  # a failure-rate estimate keeps no worlds: its worlds are G(z)
        campaign = store.open_campaign("failure-rate-s0", "toy", "return", False, "random", 2, 0, {}, resume=False)
        for slot, latent in enumerate([z, z + 5.0]):
            store.add(campaign, 0, slot, latent, 0.0, [{"return": 0.0, "reached": 0.0, "steps": 30.0}] * 4, 0.0)
    session = Session.open(run_dir).env("toy")
    indices = [i for i, e in enumerate(session.evaluations) if e.campaign in ("random-return-s0", "failure-rate-s0")]
    generator = load_generator(run_dir / "toy" / "generator")[0]
    decoded = generate(generator, np.stack([z, z + 5.0]))
    expected = [world_digest(toy_spec.world_to_arrays(jax_row(decoded, k))) for k in range(2)]
    assert session.world_keys(indices[-2:]) == expected
    first = stored(run_dir, "random-return-s0")[0]
    assert session.world_keys(indices[:1]) == [world_digest(first.world)]


def test_an_atlas_cell_opens_its_worst_world(client, toy_run):
    atlas = client.get("/api/toy/atlas").json()
    assert atlas["descriptors"] == ["wall_share", "goal_distance"] and atlas["size"] == [3, 3]
    assert atlas["cells"]
    evaluations = stored(toy_run)
    for cell in atlas["cells"]:
        world = evaluations[cell["world"]]
        assert world.campaign == "atlas-min-return-s0"
        assert world.score == pytest.approx(cell["score"])
    scores = {e.score for e in evaluations if e.campaign == "atlas-min-return-s0"}
    assert min(scores) == pytest.approx(min(c["score"] for c in atlas["cells"]))  # the worst world heads some cell


def test_exports_load_back_as_a_dataset_and_as_json(client, toy_run, tmp_path, toy_spec):
    world = stored(toy_run)[4].world
    response = client.get("/api/toy/export.npz?world=4")
    assert "attachment" in response.headers["content-disposition"]
    (tmp_path / "w.npz").write_bytes(response.content)
    dataset = WorldDataset.load(tmp_path / "w.npz", env="toy")
    assert len(dataset) == 1
    for name, value in toy_spec.world_to_arrays(dataset.world(0)).items():
        np.testing.assert_array_equal(value, world[name])
    as_json = client.get("/api/toy/export.json?world=4").json()
    assert as_json["env"] == "toy" and as_json["source"]["index"] == 4
    rebuilt = toy_spec.world_from_arrays({k: np.asarray(v) for k, v in as_json["world"].items()})
    np.testing.assert_array_equal(np.asarray(rebuilt.walls), world["walls"])
    decoded = client.get("/api/toy/export.npz?z=0,0,0")
    assert WorldDataset._from_arrays(dict(np.load(io.BytesIO(decoded.content))), tmp_path, "toy", "") is not None


BAD = [
    ("get", "/api/toy/decode.png?z=1,2", None, 400, "3 numbers"),
    ("get", "/api/toy/decode.png?z=1,nan,2", None, 400, "non-finite"),
    ("get", "/api/toy/decode.png?z=1,inf,2", None, 400, "non-finite"),
    ("get", "/api/toy/decode.png?z=1,2,1e6", None, 400, "±10"),
    ("get", "/api/toy/decode.png?z=a,b,c", None, 400, "comma-separated"),
    ("get", "/api/toy/decode.png?z=0,0,0&size=100000", None, 422, "size"),
    ("get", "/api/toy/world/999", None, 400, "not stored"),
    ("get", "/api/toy/world/-1", None, 400, "not stored"),
    ("get", "/api/nowhere/map", None, 404, "no environment"),
    ("get", "/api/toy/failures?by=luck", None, 422, "by"),
    ("get", "/api/toy/failures?limit=0", None, 422, "limit"),
    ("get", "/api/toy/failures?event=reached%20%3E", None, 400, "reached"),
    ("get", "/api/toy/failures?event=speed%20%3E%201", None, 400, "speed"),
    ("get", "/api/toy/atlas?name=elsewhere", None, 400, "no atlas"),
    ("get", "/api/toy/export.npz", None, 400, "either world"),
    ("post", "/api/toy/play", {"world": 0, "episodes": 17}, 422, "episodes"),
    ("post", "/api/toy/play", {"world": 0, "episodes": 0}, 422, "episodes"),
    ("post", "/api/toy/play", {"world": 0, "seed": -1}, 422, "seed"),
    ("post", "/api/toy/play", {"world": 0, "agent": "run"}, 400, "no agent"),
    ("post", "/api/toy/play", {"world": 0, "agent": "/etc/passwd"}, 400, "no agent"),
    ("post", "/api/toy/play", {"world": 0, "agent": "os:system"}, 400, "no agent"),
    ("post", "/api/toy/play", {"world": 0, "z": [0, 0, 0]}, 422, "either world"),
    ("post", "/api/toy/play", {"z": [0, 0]}, 400, "3 numbers"),
    ("post", "/api/toy/play", {"z": [0, 0, 1e300]}, 400, "±10"),
    ("post", "/api/toy/play", {"z": "0,0,0"}, 422, "z"),
    ("post", "/api/toy/play", {"world": 0, "agnet": "scripted/random"}, 422, "unknown field 'agnet'"),
    ("post", "/api/toy/save", {"world": 0, "path": "/tmp/x"}, 422, "unknown field 'path'"),
    ("post", "/api/toy/play", {"world": 0, "client": "../x"}, 422, "client"),
    ("get", "/api/toy/ready?episodes=99", None, 422, "episodes"),
]


@pytest.mark.parametrize(("method", "path", "body", "status", "says"), BAD, ids=[f"{m} {p} {b}" for m, p, b, *_ in BAD])
def test_a_bad_request_gets_a_one_line_json_error(client, method, path, body, status, says):
    response = client.request(method.upper(), path, json=body)
    assert response.status_code == status
    message = response.json()["error"]
    assert says in message and "\n" not in message
    assert client.get("/api/run").status_code == 200  # and the server keeps serving


def test_malformed_json_is_refused(client):
    response = client.post("/api/toy/play", content=b"{not json", headers={"content-type": "application/json"})
    assert response.status_code == 422 and "\n" not in response.json()["error"]
    assert response.json()["error"].startswith("the request body is not valid JSON (")


def test_a_large_body_is_refused_before_it_is_read(client):
    padding = "x" * (10 * 1024 * 1024)
    response = client.post("/api/toy/play", content=f'{{"world": 0, "note": "{padding}"}}', headers={"content-type": "application/json"})
    assert response.status_code == 413 and "64 KiB" in response.json()["error"]
    chunked = client.post("/api/toy/play", content=iter([b'{"world": 0}']), headers={"content-type": "application/json"})
    assert chunked.status_code == 411


def test_the_map_says_the_worlds_share_from_the_stored_random_campaign(client, toy_run, fresh_toy_run):
    from worldagent.analysis.noise import episode_values, world_share
    from worldagent.explore.session import Session

    share = client.get("/api/toy/map").json()["share"]
    evaluations = stored(toy_run, "random-return-s0")
    expected = world_share(episode_values(evaluations, "return"))
    assert share["campaign"] == "random-return-s0" and share["summary"]["worlds"] == len(evaluations) and share["summary"]["repeats"] == 4
    assert share["summary"]["metrics"]["return"]["icc"] == pytest.approx(expected.icc)
    assert share["line"].startswith(f"random-return-s0, {len(evaluations)} worlds x 4 episodes: world's share of return {expected.icc:.2f} [")
    assert "of the failure (reached < 0.5)" in share["line"]
    with RunStore(fresh_toy_run / "toy" / "store.sqlite") as store:
        store.delete_campaigns(["random-return-s0"])
    assert Session.open(fresh_toy_run).env("toy").map_data()["share"] is None  # no random campaign: nothing said


def test_the_map_marks_failing_worlds_and_says_what_its_axes_show(client, toy_run):
    found = client.get("/api/toy/map").json()
    reached = np.array([np.mean([e["reached"] for e in ev.episodes]) for ev in stored(toy_run)])
    assert found["failure"] == "reached < 0.5" and found["failing"] == (reached < 0.5).astype(int).tolist()
    assert 0 < found["explained"][1] <= found["explained"][0] and sum(found["explained"]) <= 1 + 1e-6
    (env,) = client.get("/api/run").json()["envs"]
    assert env["thresholds"] == {"reached": {"op": "<", "value": 0.5}}
    assert env["key"]["marks"] == {"goal": {"shape": "dot", "colour": "#ff00ff", "radius": 23.04, "label": "goal"}}


def test_each_failure_shows_its_nearest_passing_worlds_values(client):
    means = client.get("/api/toy/map").json()["metrics"]["reached"]
    for row in client.get("/api/toy/failures?limit=500").json()["rows"]:
        assert row["nearest_metrics"] == {"reached": pytest.approx(means[row["nearest_passing"]], abs=1e-4)} and means[row["nearest_passing"]] >= 0.5


def test_a_play_overtaken_while_it_waits_is_not_played(client, session, monkeypatch):
    """Three plays of one page: the first is playing when the second and third arrive; the second is dropped (409)."""
    import threading
    import time

    import worldagent.explore.session as explorer_session

    replay, started, played = explorer_session.replay_marked, threading.Event(), []

    def slow(*args, **kwargs):
        started.set()
        time.sleep(0.6)
        played.append(1)
        return replay(*args, **kwargs)

    monkeypatch.setattr(explorer_session, "replay_marked", slow)
    answers: dict[int, int] = {}

    def post(seq: int) -> None:
        body = {"world": 3, "agent": "scripted/homing", "episodes": 2, "client": "page-1", "seq": seq}
        answers[seq] = client.post("/api/toy/play", json=body).status_code

    first = threading.Thread(target=post, args=(1,))
    first.start()
    assert started.wait(30)
    second = threading.Thread(target=post, args=(2,))
    second.start()
    time.sleep(0.1)  # the second waits for the lock when the third comes
    post(3)
    first.join()
    second.join()
    assert answers == {1: 200, 2: 409, 3: 200} and len(played) == 2
    other = client.post("/api/toy/play", json={"world": 3, "agent": "scripted/homing", "episodes": 2, "client": "page-2", "seq": 1})
    assert other.status_code == 200  # another page's numbering is its own


def test_episodes_are_the_same_whatever_batch_they_are_played_in(session):
    """1-8 episodes replay as a batch of 8 (one compile): the first n are those a batch of n plays."""
    from worldagent.evaluation.trajectories import replay

    env = session.env("toy")
    world = env.stored_world(4)
    played = env.play(world, "scripted/random", 3, 7, 64)
    setup = env.setup("scripted/random")
    import jax

    alone = replay(env.spec, setup.env, setup.policy, world, jax.random.split(jax.random.key(7), 3), setup.params)
    assert [e["steps"] for e in played["episodes"]] == alone.steps.tolist()
    assert env.cold(["scripted/random", "nobody"], 3) == {"cold": [], "warming": None}  # compiled for 1-8 episodes; unknown labels ignored
    assert env.cold(["scripted/random"], 12)["cold"] == ["scripted/random"]  # 9-16 episodes: the second batch size, not yet compiled


def test_a_token_guards_every_request(session):
    guarded = TestClient(make_app(session, token="s3cret"), base_url="http://192.0.2.1")
    assert guarded.get("/api/run").status_code == 401
    assert guarded.get("/").json()["error"].startswith("missing or wrong token")
    assert guarded.get("/api/run", headers={"x-worldagent-token": "wrong"}).status_code == 401
    assert guarded.get("/api/run", headers={"x-worldagent-token": "s3cret"}).status_code == 200
    page = guarded.get("/?token=s3cret")
    assert page.status_code == 200 and "httponly" in page.headers["set-cookie"].lower()
    assert guarded.get("/api/toy/map").status_code == 200  # the page's cookie carries the token on


def test_without_a_token_only_the_loopback_host_is_answered(session):
    foreign = TestClient(make_app(session), base_url="http://attacker.example")
    response = foreign.get("/api/run")
    assert response.status_code == 403 and "127.0.0.1" in response.json()["error"]


def test_exploring_writes_nothing_to_the_run(toy_run, session):
    before = file_hashes(toy_run)
    client = TestClient(make_app(session), base_url=LOCAL)
    for path in ("/api/toy/map", "/api/toy/world/1.png", "/api/toy/failures", "/api/toy/atlas", "/api/toy/export.npz?world=1"):
        assert client.get(path).status_code == 200
    assert client.post("/api/toy/play", json={"world": 1, "agent": "scripted/random", "episodes": 1}).status_code == 200
    assert file_hashes(toy_run) == before


def test_an_env_without_locate_shows_its_own_picture_of_the_episodes(toy_run, toy_spec):
    import dataclasses

    from worldagent.evaluation.trajectories import Episodes
    from worldagent.explore.episodes import episodes_payload

    plain = dataclasses.replace(toy_spec, pictures=dataclasses.replace(toy_spec.pictures, locate=None))
    positions = np.array([[[0, 0], [0, 1], [1, 1]]])
    played = Episodes(
        positions, np.ones((1, 3), bool), np.array([2]), {"return": np.array([1.0]), "reached": np.array([1.0]), "steps": np.array([2.0])}
    )
    world = toy_spec.world_from_arrays(stored(toy_run)[0].world)
    payload = episodes_payload(plain, world, played, toy_spec.make_env()[1], 96)
    assert payload["episodes"][0]["path"] is None and payload["still"].startswith("data:image/png;base64,")
    animated = episodes_payload(toy_spec, world, played, toy_spec.make_env()[1], 96)
    assert animated["still"] is None and np.asarray(animated["episodes"][0]["path"]).shape == (3, 1, 2)


def test_saving_a_world_is_the_one_write(tmp_path, toy_run, toy_spec):
    import shutil

    from worldagent.explore.session import Session

    copy = tmp_path / "run"
    shutil.copytree(toy_run, copy)
    client = TestClient(make_app(Session.open(copy)), base_url=LOCAL)
    before = file_hashes(copy)
    saved = client.post("/api/toy/save", json={"world": 2}).json()["saved"]
    assert saved == str(copy / "toy" / "explorer" / "toy-world-2.npz")
    assert set(file_hashes(copy)) - set(before) == {copy / "toy" / "explorer" / "toy-world-2.npz"}
    assert all(file_hashes(copy)[p] == h for p, h in before.items())
    np.testing.assert_array_equal(WorldDataset.load(saved, env="toy").worlds.walls[0], stored(copy)[2].world["walls"])
    assert client.post("/api/toy/save", json={"z": [0, 0]}).status_code == 400


def test_another_sites_page_cannot_use_the_explorer(client):
    evil = client.post("/api/toy/save", json={"world": 0}, headers={"origin": "http://attacker.example"})
    assert evil.status_code == 403 and "cross-origin" in evil.json()["error"]
    assert client.get("/api/run", headers={"origin": "http://127.0.0.1"}).status_code == 200  # the page's own origin


def test_a_diff_written_while_serving_shows_on_the_next_request_with_its_agents(toy_spec, fresh_toy_run, add_diff):
    from worldagent.explore.session import Session

    session = Session.open(fresh_toy_run)
    client = TestClient(make_app(session), base_url=LOCAL)
    before, old_map = client.get("/api/run").json()["envs"][0], client.get("/api/toy/map").json()
    assert before["diffs"] == [] and not any(a.startswith("diff") for a in before["agents"])
    assert client.get("/api/toy/diff").status_code == 400
    add_diff(toy_spec, fresh_toy_run, {"diff-late-s0": (("homing", "random"), 2)})  # `worldagent diff --out` into the served run
    found = client.get("/api/toy/diff").json()  # the same server, not restarted
    late = stored(fresh_toy_run, "diff-late-s0")
    by_hand = sum(np.mean([e["reached"] for e in ev.episodes]) < 0.5 <= np.mean([e["A.reached"] for e in ev.episodes]) for ev in late)
    assert (found["campaign"], found["worlds"], found["regressed"]) == ("diff-late-s0", len(late), by_hand) and by_hand > 0
    assert found["agents"] == ["diff/A", "diff/B"] and found["pair"] == {"A": "scripted homing", "B": "scripted random"}
    assert found["campaign_words"]["diff-late-s0"] == "Diff of two agents on given worlds, 24 worlds, seed 0"  # the page's select names it in words
    after = client.get("/api/run").json()["envs"][0]
    assert after["diffs"] == ["diff-late-s0"] and {"diff/A", "diff/B"} <= set(after["agents"]) and after["worlds"] == before["worlds"] + len(late)
    new_map, n = client.get("/api/toy/map").json(), len(old_map["x"])
    assert new_map["x"][:n] == old_map["x"] and new_map["campaign"][:n] == old_map["campaign"]  # earlier worlds keep their indices and places
    assert new_map["campaigns"][-1] == "diff-late-s0" and len(new_map["x"]) == n + len(late)
    assert client.get(f"/api/toy/world/{found['rows'][0]['index']}").json()["campaign"] == "diff-late-s0"
    assert session.env("toy").rescan() == 0  # nothing new: nothing read again
