"""benchmarks/README.md indexes every benchmark script and names only files that exist (issue 49, item 5).

Pure reads of the checkout: no benchmark is imported or run.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
INDEX = BENCHMARKS / "README.md"
SCRIPT_FOLDERS = (BENCHMARKS, BENCHMARKS / "studies")
SCRIPT_SUFFIXES = {".py", ".sh"}
# Where a benchmark's path is written as the way to run or read it. Result JSONs, and the index
# quoting their commands, are records of what ran and keep the paths of their day.
REFERRING = ("README.md", "docs", "src", "tests", ".ci", "examples", "benchmarks")
RECORDS = (INDEX,)
TEXT_SUFFIXES = {".md", ".py", ".sh", ".toml", ".yml", ".yaml", ""}
SKIPPED_FOLDERS = {"results", ".venv", "build", "dist", "node_modules", "__pycache__", "site"}
INDEX_ROW = re.compile(r"^\| \[`([^`]+)`\]\(([^)]+)\)", re.MULTILINE)
LINK = re.compile(r"\]\(([^)#\s]+)")
SCRIPT_PATH = re.compile(r"benchmarks/[\w/]+\.(?:py|sh)\b")


def scripts_on_disk() -> set[str]:
    """Every script in benchmarks/ and benchmarks/studies/, relative to benchmarks/."""
    return {p.relative_to(BENCHMARKS).as_posix() for folder in SCRIPT_FOLDERS for p in folder.iterdir() if p.suffix in SCRIPT_SUFFIXES}


def indexed_scripts(text: str) -> dict[str, str]:
    """The script each index row names in its first cell, ``[`NAME`](TARGET)``: {NAME: TARGET}."""
    return dict(INDEX_ROW.findall(text))


def relative_links(text: str) -> set[str]:
    """Markdown link targets that are paths in the checkout (not URLs)."""
    return {target for target in LINK.findall(text) if "://" not in target}


def referring_files(root: Path) -> list[Path]:
    """The text files under ``REFERRING`` that could name a benchmark script."""
    files = []
    for name in REFERRING:
        top = root / name
        candidates = [top] if top.is_file() else top.rglob("*")
        files += [
            p
            for p in candidates
            if p.is_file()
            and p.suffix in TEXT_SUFFIXES
            and p not in RECORDS
            and not SKIPPED_FOLDERS.intersection(p.relative_to(root).parts)
            and ".egg-info" not in str(p)
        ]
    return files


def test_every_script_is_indexed_and_every_indexed_script_exists():
    indexed = indexed_scripts(INDEX.read_text())
    on_disk = scripts_on_disk()
    assert not on_disk - indexed.keys(), f"scripts missing from benchmarks/README.md: {sorted(on_disk - indexed.keys())}"
    assert not indexed.keys() - on_disk, f"benchmarks/README.md indexes scripts that do not exist: {sorted(indexed.keys() - on_disk)}"
    assert all(name == target for name, target in indexed.items()), "an index row's link points elsewhere than the script it names"


def test_every_result_is_indexed_and_every_link_resolves():
    text = INDEX.read_text()
    links = relative_links(text)
    broken = sorted(target for target in links if not (BENCHMARKS / target).exists())
    assert not broken, f"benchmarks/README.md links to files that do not exist: {broken}"
    results = {f"results/{p.name}" for p in (BENCHMARKS / "results").glob("*.json")}
    assert not results - links, f"result files missing from benchmarks/README.md: {sorted(results - links)}"


def test_every_named_benchmark_script_exists():
    missing = {
        f"{path.relative_to(ROOT)}: {name}"
        for path in referring_files(ROOT)
        for name in SCRIPT_PATH.findall(path.read_text(errors="replace"))
        if not (ROOT / name).exists()
    }
    assert not missing, f"paths to benchmark scripts that do not exist (moved to benchmarks/studies/?): {sorted(missing)}"


def test_the_checks_see_what_they_check(tmp_path):
    """The parsers find a row, a link and a stale path where they are, so an empty match cannot pass."""
    row = "| [`studies/a.py`](studies/a.py) | x | [`r.json`](results/r.json) | — |"
    assert indexed_scripts(row) == {"studies/a.py": "studies/a.py"}
    assert relative_links(row + " [site](https://example.org)") == {"studies/a.py", "results/r.json"}
    (tmp_path / "docs").mkdir()
    gone = "benchmarks/" + "gone.py"  # spelt apart, so that this file does not name it
    (tmp_path / "docs" / "page.md").write_text(f"run `python {gone}`")
    (tmp_path / "benchmarks" / "results").mkdir(parents=True)
    (tmp_path / "benchmarks" / "results" / "old.json").write_text(f'{{"command": "python {gone}"}}')
    found = [SCRIPT_PATH.findall(p.read_text()) for p in referring_files(tmp_path)]
    assert found == [[gone]]
