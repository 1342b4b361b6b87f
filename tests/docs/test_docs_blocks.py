"""Every code block of the README and the documentation pages runs, parses, or says why it cannot (issue 49, item 3).

``pytest -m docs`` (a step of .ci/run): blocks that run do so at tiny sizes on one tiny run directory standing for
``runs/quick`` (tiny_run.py), and print what the page shows after them; ``doc_blocks.py`` says how each block
is chosen and rewritten.
"""

from __future__ import annotations

import pytest
from block_runner import run_python_block, run_shell_block
from doc_blocks import all_blocks, marker_problem, missing_files, output_problem, prepared

pytestmark = pytest.mark.docs

BLOCKS = all_blocks()


def test_the_pages_have_blocks_of_every_kind():
    kinds = {block.kind for block in BLOCKS}
    assert {"runs", "parses", "illustrative"} <= kinds
    assert any(block.page == "README.md" for block in BLOCKS)


@pytest.mark.parametrize("block", BLOCKS, ids=[block.id for block in BLOCKS])
def test_block(block, tiny_run, page_state):
    problem = marker_problem(block)
    assert problem is None, problem
    missing = missing_files(block.code)
    assert not missing, f"{block.id} names {', '.join(missing)}, not in the repository"
    if block.kind == "illustrative":
        return
    cwd, namespace = page_state(block.page)
    code = prepared(block.code, block.replacements, tiny_run)
    if block.language == "python":
        assert block.kind == "runs", f"{block.id}: a Python block runs or is illustrative"
        printed = run_python_block(code, namespace, cwd, block.id)
    else:
        printed = run_shell_block(code, cwd, parse_only=block.kind == "parses")
    if block.output is not None and block.kind == "runs":
        problem = output_problem(block.output, printed)
        assert problem is None, f"{block.id}: {problem}"
