"""What the wheel ships, checked from pyproject.toml without building it (.ci/wheel_check.py builds and runs it).

setuptools puts a package's modules in the wheel, but a data file only when [tool.setuptools.package-data]
names it, and a folder of modules only when it has an __init__.py: either omission passes every test
of an editable install and breaks an installed one.
"""

import fnmatch
import tomllib
from pathlib import Path

from typer.testing import CliRunner

import worldagent
from worldagent.cli import app

ROOT = Path(__file__).resolve().parents[1]
SOURCE = ROOT / "src"
PACKAGE = SOURCE / "worldagent"


def pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def package_files(suffix_is_python: bool) -> list[Path]:
    """The package's files (not caches, not hidden files), Python modules or the rest."""
    return sorted(
        p
        for p in PACKAGE.rglob("*")
        if p.is_file() and "__pycache__" not in p.parts and not p.name.startswith(".") and (p.suffix == ".py") == suffix_is_python
    )


def declared(path: Path, package_data: dict[str, list[str]]) -> bool:
    """Whether a package-data glob of the package holding ``path`` (or of a package above it) matches it."""
    for package, patterns in package_data.items():
        folder = SOURCE.joinpath(*package.split("."))
        if path.is_relative_to(folder):
            relative = path.relative_to(folder).as_posix()
            if any(fnmatch.fnmatch(relative, pattern) for pattern in patterns):
                return True
    return False


def test_every_data_file_of_the_package_is_declared_as_package_data():
    package_data = pyproject()["tool"]["setuptools"]["package-data"]
    data_files = package_files(suffix_is_python=False)
    assert data_files, "the package ships data files (the explorer's page, racing's fitted map)"
    undeclared = [p.relative_to(ROOT).as_posix() for p in data_files if not declared(p, package_data)]
    assert not undeclared, f"not in [tool.setuptools.package-data], so missing from the wheel: {undeclared}"


def test_declared_matches_only_what_a_glob_names():
    package_data = {"worldagent.explore": ["static/*"]}
    assert declared(PACKAGE / "explore" / "static" / "index.html", package_data)
    assert not declared(PACKAGE / "envs" / "racing" / "open_inverse.npz", package_data)
    assert not declared(PACKAGE / "explore" / "notes.txt", package_data)


def test_every_folder_of_modules_is_a_package():
    folders = {p.parent for p in package_files(suffix_is_python=True)}
    assert not [f.relative_to(ROOT).as_posix() for f in folders if not (f / "__init__.py").is_file()]


def test_the_version_has_one_source_and_the_cli_prints_it():
    project = pyproject()
    assert "version" not in project["project"] and "version" in project["project"]["dynamic"]
    assert project["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "worldagent.__version__"}
    result = CliRunner().invoke(app, ["--version"])
    assert result.exit_code == 0 and result.output.strip() == f"worldagent {worldagent.__version__}"


def test_the_changelog_has_a_section_for_the_version():
    headings = [line for line in (ROOT / "CHANGELOG.md").read_text().splitlines() if line.startswith("## [")]
    assert any(line.startswith(f"## [{worldagent.__version__}]") for line in headings), headings
