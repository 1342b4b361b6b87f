"""The example environment package ``examples/lavagrid`` used as a stranger uses it (issue 30, item 9).

It registers only through the ``worldagent.envs`` entry point, so these tests run where it is
installed (CI: ``pip install -e examples/lavagrid``) and are skipped elsewhere. The conformance
suite (``tests/envs/test_conformance.py``) covers its env contract; here the CLI's tiny
``reproduce`` runs every phase on it (~30 s on 2 idle cores).
"""

from __future__ import annotations

import math
import re

import pytest
from typer.testing import CliRunner

from worldagent.cli import app
from worldagent.envs import registry

lavagrid_spec = pytest.importorskip("lavagrid.spec", reason="the example env is not installed: pip install -e examples/lavagrid")


def test_the_example_env_is_registered_through_its_entry_point_only():
    from importlib.metadata import entry_points

    (entry,) = [entry for entry in entry_points(group=registry.ENTRY_POINT_GROUP) if entry.name == "lavagrid"]
    assert entry.value == "lavagrid.spec:SPEC"
    assert registry.get("lavagrid") is lavagrid_spec.SPEC
    assert "lavagrid" not in registry.BUILTIN


@pytest.mark.example  # its own step in .ci/run, outside the default run's 5 minutes
def test_reproduce_tiny_runs_every_phase_on_the_example_env(tmp_path):
    result = CliRunner().invoke(app, ["reproduce", "--preset", "tiny", "--env", "lavagrid", "--out", str(tmp_path), "--quiet"])
    assert result.exit_code == 0, result.output
    html = (tmp_path / "report.html").read_text()
    assert "<h3>lavagrid</h3>" in html
    values = dict(re.findall(r'data-key="([^"]+)" data-value="([^"]+)"', html))
    assert math.isfinite(float(values["lavagrid.random.mean_raw"]))
    assert 0.0 <= float(values["lavagrid.random.mean_normalised"]) <= 1.0
