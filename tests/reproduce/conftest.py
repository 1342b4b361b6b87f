"""One tiny reproduce run of racing, shared by the tests of this folder (built once per session)."""

from __future__ import annotations

import shutil

import pytest

from worldagent.reproduce.pipeline import reproduce
from worldagent.reproduce.presets import get_preset

SHARED_RUN = ("racing_run", "racing_copy")


@pytest.hookimpl(tryfirst=True)  # before pytest's -m selection reads the marks
def pytest_collection_modifyitems(items):
    """A test of the shared tiny run is an integration test: building the run compiles every phase (minutes on 2 cores)."""
    for item in items:
        if set(SHARED_RUN) & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.integration)


@pytest.fixture(scope="session")
def racing_run(tmp_path_factory):
    """(run directory, status lines) of the tiny preset run end to end on racing."""
    out = tmp_path_factory.mktemp("reproduce") / "tiny"
    lines: list[str] = []
    reproduce(get_preset("tiny"), out, ["racing"], progress=False, echo=lines.append)
    return out, lines


@pytest.fixture
def racing_copy(racing_run, tmp_path):
    """A private copy of the finished racing run, for tests that change it."""
    out = tmp_path / "copy"
    shutil.copytree(racing_run[0], out)
    return out
