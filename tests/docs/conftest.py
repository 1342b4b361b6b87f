"""Fixtures of the documentation blocks' tests: the tiny run they share, and each page's scratch folder and namespace."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

# The helpers beside this file (doc_blocks, block_runner, tiny_run) import one another by name, under any --import-mode.
if str(Path(__file__).parent) not in sys.path:
    sys.path.insert(0, str(Path(__file__).parent))

from tiny_run import build_tiny_run  # noqa: E402


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory) -> Path:
    """The run directory that stands for ``runs/quick`` in every block, built once (or, to rerun the blocks
    without building it again, one built before and named by ``WORLDAGENT_DOCS_RUN``)."""
    if os.environ.get("WORLDAGENT_DOCS_RUN"):
        return Path(os.environ["WORLDAGENT_DOCS_RUN"])
    return build_tiny_run(tmp_path_factory.mktemp("docs") / "quick")


@pytest.fixture(scope="session")
def page_state(tmp_path_factory):
    """Each page's working directory and Python namespace, made on first use: a page's blocks share them, in order."""
    states: dict[str, tuple[Path, dict]] = {}

    def state(page: str) -> tuple[Path, dict]:
        if page not in states:
            folder = tmp_path_factory.mktemp(page.replace("/", "-").removesuffix(".md"))
            states[page] = (folder, {"__name__": f"docs:{page}"})
        return states[page]

    return state
