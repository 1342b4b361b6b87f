"""``worldagent explore``: refusals before anything is served, and the token a non-local host gets."""

from __future__ import annotations

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
    lines.clear()
    server.serve(session, echo=lines.append)
    assert lines[0].startswith("worldagent explore: http://127.0.0.1:8765/ ")  # local: no token needed
