"""The documentation harness itself (doc_blocks, block_runner, quoted_figures): pure and fast, in the default suite,
so that a harness that stopped catching broken examples fails before the docs step would have caught nothing."""

from __future__ import annotations

import json

import pytest
from block_runner import BlockFailed, parse_worldagent, run_python_block, run_shell_block
from doc_blocks import ROOT, all_blocks, blocks_of, cut_budgets, logical_lines, marker_problem, missing_files, output_problem, prepared
from quoted_figures import quote_problem, quotes_of, recorded, shown_value

PAGE = """Intro.

```bash
worldagent evaluate random racing --agent runs/quick/racing/agent \\
    --worlds 1000 --out runs/evaluate   # Figure 6a
```

<!-- illustrative: starts a server that runs until Ctrl-C -->
```bash
worldagent explore runs/quick
```

<!-- illustrative: -->
```python
print(1)
```

<!-- runs: at 16 worlds: "1000" -> "16" -->
```python
print(sum(range(1000)))
```

```text
sum 120
...
done
```
"""


def test_blocks_are_read_with_their_markers_and_printed_output():
    blocks = blocks_of(PAGE, "page.md")
    assert [(b.line, b.language, b.kind) for b in blocks] == [
        (3, "shell", "runs"),
        (9, "shell", "illustrative"),
        (14, "python", "illustrative"),
        (19, "python", "runs"),
    ]
    assert blocks[1].note == "starts a server that runs until Ctrl-C"
    assert blocks[3].replacements == (("1000", "16"),)
    assert blocks[3].output == "sum 120\n...\ndone"
    assert blocks[0].output is None
    assert marker_problem(blocks[2]) is not None  # illustrative with no reason
    assert marker_problem(blocks[1]) is None
    (console,) = blocks_of("```console\n$ worldagent envs\nracing  ...\n```\n", "p.md")
    assert (console.language, console.code, console.output) == ("shell", "worldagent envs", "racing  ...")
    assert marker_problem(blocks_of("<!-- run: x y z -->\n```bash\nls\n```\n", "p.md")[0]) is not None  # a misspelt kind


def test_a_block_runs_on_the_tiny_run_at_tiny_sizes(tmp_path):
    block = blocks_of(PAGE, "page.md")[0]
    code = prepared(block.code, block.replacements, tmp_path / "tiny")
    (line,) = logical_lines(code)
    assert f"--agent {tmp_path / 'tiny'}/racing/agent" in line and "runs/evaluate" in line
    assert cut_budgets(["evaluate", "random", "racing", "--worlds", "1000", "--repeats", "16", "--seed", "3"]) == [
        "evaluate",
        "random",
        "racing",
        "--worlds",
        "8",
        "--repeats",
        "2",
        "--seed",
        "3",
    ]
    assert cut_budgets(["atlas", "racing", "--budget", "2100"]) == ["atlas", "racing", "--budget", "21", "--cells", "4", "--confirm", "2"]
    assert cut_budgets(["atlas", "racing", "--cells", "3"]) == ["atlas", "racing", "--cells", "3", "--confirm", "2"]
    assert cut_budgets(["train", "racing", "--worlds", "vae"])[-1] == "vae"  # not a budget
    with pytest.raises(AssertionError, match="does not contain"):
        prepared("print(1)", (("1000", "16"),), tmp_path)


def test_heredocs_and_continuations_make_one_line_each():
    code = "cat > m.py <<'PY'\nx = 1\n\nPY\n# a comment\nworldagent envs \\\n  --help\n"
    assert logical_lines(code) == ["cat > m.py <<'PY'\nx = 1\n\nPY", "worldagent envs  --help"]


def test_printed_output_may_differ_in_numbers_not_words():
    expected = "found 0.625 (8 episodes); confirmed 0.4062 [0.2851, 0.5363]\n...\n{'picked': 13,\n 'rate': 0.04}"
    assert output_problem(expected, "found 1 (2 episodes); confirmed 1 [0.5, 1]\nanother line\n{'picked': 120, 'rate': n/a}\n") is None
    assert output_problem(expected, "found 1 (2 episodes); confirmed 1 [0.5, 1]\n{'chosen': 120, 'rate': 0.1}") is not None
    assert output_problem("sum 120", "total 120") is not None


def test_a_broken_example_fails(tmp_path):
    with pytest.raises(BlockFailed, match="No such option"):
        parse_worldagent(["evaluate", "random", "racing", "--agent", "a", "--generator", "g", "--wrolds", "8"])
    with pytest.raises(BlockFailed, match="No such command"):
        parse_worldagent(["evaluate", "randomly", "racing"])
    with pytest.raises(BlockFailed, match="Missing option"):
        run_shell_block("worldagent evaluate random racing --worlds 8", tmp_path, parse_only=True)
    with pytest.raises(ImportError):
        run_python_block("from worldagent.store import RunStores", {}, tmp_path, "page.md:1")  # a renamed class
    with pytest.raises(BlockFailed, match="exited"):
        run_shell_block("python -c 'import sys; sys.exit(3)'", tmp_path)
    gone = "benchmarks/" + "no_such_script.py"  # spelt apart: test_benchmarks_index reads this file for script paths
    assert missing_files(f"python {gone} --out runs/x") == [gone]
    assert missing_files("python benchmarks/device_check.py --smoke; pip install -e examples/ued_maze") == []
    parse_worldagent(["evaluate", "random", "racing", "--agent", "a", "--generator", "g", "--worlds", "8"])  # the right one parses


def test_a_python_block_shares_its_page_namespace(tmp_path):
    namespace: dict = {}
    run_python_block("x = 2", namespace, tmp_path, "p.md:1")
    assert run_python_block("print(x * 21)", namespace, tmp_path, "p.md:5") == "42\n"


def test_every_block_of_the_pages_says_how_it_is_checked():
    problems = [marker_problem(block) for block in all_blocks()]
    assert not [problem for problem in problems if problem], problems


# -- quoted figures ---------------------------------------------------------------------------------------


def test_a_quoted_figure_matches_its_result_file(tmp_path):
    (tmp_path / "r.json").write_text(
        json.dumps({"seconds": 9.88, "phases": {"a/x": {"wall_s": 60.0}, "a/y": {"wall_s": 30.0}, "b/x": {"wall_s": 1}}})
    )
    page = "took 9.9 s<!-- from: r.json seconds --> and 1½ min<!-- from: r.json phases.a/*.wall_s /60 -->; 9.8 s<!-- from: r.json seconds -->"
    quotes = quotes_of(page, "p.md")
    assert [q.shown for q in quotes] == ["9.9", "1½", "9.8"]
    assert quote_problem(quotes[0], tmp_path) is None
    assert quote_problem(quotes[1], tmp_path) is None
    assert "records 9.88" in quote_problem(quotes[2], tmp_path)
    assert "not in the repository" in quote_problem(quotes_of("1 s<!-- from: nope.json seconds -->", "p.md")[0], tmp_path)
    assert recorded({"a": [1, 2]}, "a.1") == 2.0
    assert recorded({"p": {"a/x": 60.0, "a/y": 30.0, "b/x": 1}}, "p.a/x+p.b/x") == 61.0  # whole keys summed
    with pytest.raises(KeyError):
        recorded({"a": "text"}, "a")
    assert shown_value("1,234") == (1234.0, 0.5) and shown_value("0.021") == (0.021, 0.0005)
    assert [q.shown for q in quotes_of("fell by −0.02<!-- from: r.json a --> [-1.5<!-- from: r.json b -->, 3<!-- from: r.json c -->]", "p.md")] == [
        "−0.02",
        "-1.5",
        "3",
    ]
    assert shown_value("−0.02") == (-0.02, 0.005)


def test_every_quoted_figure_matches_its_result_file():
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    quotes = [quote for path in pages for quote in quotes_of(path.read_text(), path.relative_to(ROOT).as_posix())]
    assert quotes, "no figure is marked with its result file"
    problems = [problem for quote in quotes if (problem := quote_problem(quote, ROOT))]
    assert not problems, "\n".join(problems)
