"""``worldagent explore``: refusals before anything is served, and the token a non-local host gets."""

from __future__ import annotations

import socket

from typer.testing import CliRunner

from worldagent.cli import app
from worldagent.explore import server


def test_explore_refuses_what_is_not_a_run(tmp_path):
    runner = CliRunner()
    missing = runner.invoke(app, ["explore", str(tmp_path / "nowhere")])
    assert missing.exit_code == 2 and "is not a directory" in missing.output
    empty = runner.invoke(app, ["explore", str(tmp_path)])
    assert empty.exit_code == 2 and "no manifest.json" in empty.output
    port = runner.invoke(app, ["explore", str(tmp_path), "--port", "0"])
    assert port.exit_code == 2 and "--port 0" in port.output


def test_a_non_local_host_gets_a_token(monkeypatch, session):
    served = {}
    monkeypatch.setattr("uvicorn.run", lambda app, host, port, log_level: served.update(host=host, port=port))
    lines: list[str] = []
    server.serve(session, host="0.0.0.0", port=9000, echo=lines.append)
    assert served == {"host": "0.0.0.0", "port": 9000}
    assert "?token=" in lines[0] and len(lines[0].split("?token=")[1].split()[0]) >= 20
    assert f"http://{socket.gethostname()}:9000/?token=" in lines[0] and "0.0.0.0" not in lines[0]  # an address others can open
    assert "every address" in lines[1]
    lines.clear()
    server.serve(session, echo=lines.append)
    assert lines[0].startswith("worldagent explore: http://127.0.0.1:8765/ ")  # local: no token needed


def test_a_store_with_its_generator_is_explored_without_a_run_directory(toy_spec, toy_run):
    from fastapi.testclient import TestClient

    from worldagent.commands.explore import open_run
    from worldagent.explore.session import Session

    run = open_run(None, toy_run / "toy" / "store.sqlite", toy_run / "toy" / "generator", "homing", "")
    client = TestClient(server.make_app(Session.of(run)), base_url="http://127.0.0.1")
    (env,) = client.get("/api/run").json()["envs"]
    assert env["name"] == "toy" and env["worlds"] == 48 and env["agents"][0] == "run"
    assert client.get("/api/toy/world/0.png").status_code == 200


def test_parts_are_checked(toy_run, tmp_path):
    runner = CliRunner()
    both = runner.invoke(app, ["explore", str(toy_run), "--store", str(toy_run / "toy" / "store.sqlite")])
    assert both.exit_code == 2 and "not both" in both.output
    alone = runner.invoke(app, ["explore", "--store", str(toy_run / "toy" / "store.sqlite")])
    assert alone.exit_code == 2 and "--generator" in alone.output
    no_generator = runner.invoke(app, ["explore", "--store", str(toy_run / "toy" / "store.sqlite"), "--generator", str(tmp_path)])
    assert no_generator.exit_code == 2 and "holds no generator" in no_generator.output
    other = runner.invoke(
        app, ["explore", "--store", str(toy_run / "toy" / "store.sqlite"), "--generator", str(toy_run / "toy" / "generator"), "--env", "racing"]
    )
    assert other.exit_code == 2 and "not racing worlds" in other.output


def test_warm_up_compiles_every_agent_in_the_background_while_serving(toy_spec, toy_run):
    from worldagent.commands.explore import warm_in_background
    from worldagent.explore.session import Session

    session = Session.open(toy_run)
    env = session.env("toy")
    assert env.cold(list(env.agents), 8)["cold"] == list(env.agents)
    warm_in_background(session).join(timeout=120)
    assert env.cold(list(env.agents), 8) == {"cold": [], "warming": None}
