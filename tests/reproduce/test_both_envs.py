"""The tiny preset end to end on both environments, as ``worldagent reproduce --preset tiny`` runs it."""

from __future__ import annotations

import json
import re

import pytest
from typer.testing import CliRunner

from worldagent.cli import app
from worldagent.reproduce.presets import PHASES

pytestmark = pytest.mark.integration  # whole-pipeline work: .ci/run's integration step runs it


@pytest.mark.slow
def test_tiny_preset_runs_both_environments_from_the_command_line(tmp_path):
    out = tmp_path / "tiny"
    result = CliRunner().invoke(app, ["reproduce", "--preset", "tiny", "--env", "all", "--out", str(out), "--quiet"])
    assert result.exit_code == 0, result.output
    manifest = json.loads((out / "manifest.json").read_text())
    for env in ("racing", "harvest"):
        for phase in PHASES:
            assert manifest["phases"][f"{env}/{phase}"]["status"] == "done", (env, phase, manifest["phases"][f"{env}/{phase}"].get("error"))
    page = (out / "report.html").read_text()
    values = dict(re.findall(r'data-key="([^"]+)" data-value="([^"]+)"', page))
    for key in (
        "racing.random.mean_normalised",
        "harvest.random.mean_normalised",
        "harvest.min.normalised",
        "harvest.max.normalised",
        "harvest.influence.conflict_default",
        "harvest.influence.equality_influenced",
    ):
        assert values[key] != "nan", key
