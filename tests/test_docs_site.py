"""The documentation site's hooks (docs/hooks.py): the generated CLI reference, the benchmarks index re-based
into docs/, and links to repository files checked and rewritten (issue 49, item 2).

Pure functions over strings and a scratch folder; ``mkdocs build --strict`` itself runs in .ci/run.
"""

from __future__ import annotations

import importlib.util
import logging
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def hooks():
    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "docs" / "hooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_cli_reference_lists_every_command_and_option(hooks):
    import typer

    from worldagent.cli import app

    page = hooks.cli_reference()
    root = typer.main.get_command(app)

    def walk(path, command):
        yield path, command
        for name, sub in getattr(command, "commands", {}).items():
            yield from walk([*path, name], sub)

    for path, command in walk(["worldagent"], root):
        if len(path) > 1:
            assert f"`{' '.join(path)}`" in page, f"{' '.join(path)} missing from the CLI reference"
        for param in command.params:
            if param.param_type_name == "option" and param.name != "help":
                assert f"`{param.opts[0]}" in page, f"{' '.join(path)} {param.opts[0]} missing from the CLI reference"
    assert "worldagent evaluate random [OPTIONS] ENV" in page


def test_benchmark_links_are_rebased_into_docs(hooks):
    text = "[`a.py`](a.py), [r](results/r.json), [page](../docs/racing.md#x), [site](https://example.org)\n```\n[code](kept.md)\n```\n"
    rebased = hooks.rebase_links(text, "benchmarks", "docs")
    assert "[`a.py`](../benchmarks/" + "a.py)" in rebased  # spelt apart: test_benchmarks_index reads this file for script paths
    assert "[r](../benchmarks/results/r.json)" in rebased
    assert "[page](racing.md#x)" in rebased
    assert "[site](https://example.org)" in rebased
    assert "[code](kept.md)" in rebased  # inside a fence: not a link


def test_repository_links_are_checked_and_rewritten(hooks, tmp_path, caplog):
    (tmp_path / "docs").mkdir()
    (tmp_path / "src").mkdir()
    (tmp_path / "src" / "x.py").write_text("")
    page = "[`src/x.py`](../src/x.py), [gone](../src/gone.py), [a page](other.md), [site](https://example.org)"
    with caplog.at_level(logging.WARNING, logger="mkdocs.hooks.worldagent"):
        plain = hooks.repository_links(page, "page.md", tmp_path, tmp_path / "docs", None)
        linked = hooks.repository_links(page, "page.md", tmp_path, tmp_path / "docs", "https://github.com/o/r")
    assert plain.startswith("`src/x.py`, ")  # no repository to link to: the path, unlinked
    assert "[`src/x.py`](https://github.com/o/r/blob/main/src/x.py)" in linked
    assert "[a page](other.md)" in plain and "[site](https://example.org)" in plain
    assert [r.getMessage() for r in caplog.records] == ["page.md links to src/gone.py, which is not in the repository"] * 2
