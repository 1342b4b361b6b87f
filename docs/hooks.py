"""MkDocs hooks of the documentation site (``mkdocs.yml``: ``hooks: [docs/hooks.py]``).

Three pages or parts of pages come from the code rather than from hand-written Markdown, so that
they cannot go stale:

- ``reference/cli.md``: every ``worldagent`` command and option, read from the typer app at build
  time (``cli_reference``), exactly as ``--help`` prints them.
- ``benchmarks.md``: ``benchmarks/README.md``, the benchmarks' index, with its links re-based from
  ``benchmarks/`` to ``docs/`` (``benchmarks_page``).
- Links from a page to a file of the repository outside ``docs/`` (``../src/...``, ``../tests/...``)
  work on GitHub but not on the site: each is checked to exist (a missing one is a warning, so
  ``mkdocs build --strict`` fails) and becomes a link to the repository when ``repo_url`` is set,
  else the plain path (``repository_links``).
"""

from __future__ import annotations

import logging
import posixpath
import re
from pathlib import Path

log = logging.getLogger("mkdocs.hooks.worldagent")  # under "mkdocs": its warnings fail a --strict build

CLI_PAGE = "reference/cli.md"
BENCHMARKS_PAGE = "benchmarks.md"
BENCHMARKS_INDEX = Path("benchmarks") / "README.md"
FENCE = re.compile(r"^(```|~~~)", re.MULTILINE)
LINK = re.compile(r"(!?\[[^\]\n]*\])\(([^)\s#]+)(#[^)\s]*)?\)")


# -- the CLI reference ------------------------------------------------------------------------


# Typer builds its commands on a copy of click of its own (typer._click): commands and parameters are read by
# duck typing, never by click's classes.


def is_group(command) -> bool:
    """A command with subcommands (``worldagent evaluate``, ``worldagent generator``, the app itself)."""
    return hasattr(command, "commands")


def usage(path: list[str], command) -> str:
    """``worldagent evaluate random [OPTIONS] ENV``: the command's path, then its arguments."""
    arguments = []
    for param in command.params:
        if param.param_type_name == "argument":
            name = param.name.upper() + ("..." if param.nargs == -1 else "")
            arguments.append(name if param.required else f"[{name}]")
    return " ".join([*path, "[OPTIONS]", *arguments])


def option_rows(command, context) -> list[str]:
    """One Markdown table row per argument and option, as ``--help`` words them (``--help`` itself left out)."""
    rows = []
    for param in command.get_params(context):
        record = param.get_help_record(context)
        if record is None or param.name == "help":
            continue
        name, text = record
        rows.append(f"| `{name}` | {escape_cell(text)} |")
    return rows


def escape_cell(text: str) -> str:
    """Help text fit for one Markdown table cell: one line, pipes escaped."""
    return " ".join(text.split()).replace("|", "\\|")


def command_section(path: list[str], command, parent) -> list[str]:
    """The Markdown of one command, and of each subcommand of a group after it."""
    context = command.context_class(command, info_name=path[-1], parent=parent)
    level = "#" * min(len(path), 4)  # the app is the page's title; its commands are sections
    lines = [f"{level} `{' '.join(path)}`", ""]
    help_text = (command.help or "").replace("\b\n", "").strip()
    if help_text:
        lines += [help_text, ""]
    if is_group(command):
        names = sorted(command.commands)
        lines += ["Commands: " + ", ".join(f"`{name}`" for name in names) + ".", ""]
        if len(path) == 1:
            lines += option_table(command, context)
        for name in names:
            lines += command_section([*path, name], command.commands[name], context)
        return lines
    lines += ["```text", usage(path, command), "```", ""]
    return lines + option_table(command, context)


def option_table(command, context) -> list[str]:
    rows = option_rows(command, context)
    return ["| argument or option | meaning |", "| --- | --- |", *rows, ""] if rows else []


def cli_reference() -> str:
    """The CLI reference page: every command of the ``worldagent`` typer app, with its options."""
    import typer

    from worldagent.cli import app

    root = typer.main.get_command(app)
    intro = [
        "# Command-line reference",
        "",
        "Generated from the `worldagent` command itself when the site is built (`docs/hooks.py`), so it lists",
        "every command and option of the installed version: `worldagent COMMAND --help` prints the same.",
        "Environment names in the help text are the environments registered where the site was built.",
        "",
    ]
    return "\n".join(intro + command_section(["worldagent"], root, None)[2:]) + "\n"


# -- the benchmarks index -----------------------------------------------------------------------


def rebase_links(markdown: str, source_dir: str, page_dir: str) -> str:
    """Relative link targets written from ``source_dir`` rewritten to work from ``page_dir`` (both relative to the repository)."""

    def rebased(match: re.Match) -> str:
        label, target, anchor = match.group(1), match.group(2), match.group(3) or ""
        if "://" in target or target.startswith(("/", "mailto:")):
            return match.group(0)
        moved = posixpath.relpath(posixpath.normpath(posixpath.join(source_dir, target)), page_dir)
        return f"{label}({moved}{anchor})"

    return outside_code(markdown, lambda text: LINK.sub(rebased, text))


def benchmarks_page(root: Path) -> str:
    """``benchmarks/README.md`` as a page of ``docs/``."""
    text = (root / BENCHMARKS_INDEX).read_text()
    return rebase_links(text, BENCHMARKS_INDEX.parent.as_posix(), "docs")


# -- links to the repository ------------------------------------------------------------------------


def outside_code(markdown: str, change) -> str:
    """``change`` applied to the Markdown outside fenced code blocks (a fence's contents are never links)."""
    parts = re.split(r"(^(?:```|~~~).*?^(?:```|~~~)[^\n]*$)", markdown, flags=re.MULTILINE | re.DOTALL)
    return "".join(part if FENCE.match(part) else change(part) for part in parts)


def repository_links(markdown: str, page_path: str, root: Path, docs: Path, repo_url: str | None) -> str:
    """Links from the page ``page_path`` (relative to ``docs``) to files of the repository outside ``docs/``: each
    checked to exist, then pointed at ``repo_url`` or, with none, left as the plain path."""
    page_dir = (docs / page_path).parent

    def resolved(match: re.Match) -> str:
        label, target = match.group(1), match.group(2)
        if "://" in target or target.startswith(("/", "mailto:")):
            return match.group(0)
        path = (page_dir / target).resolve()
        if path.is_relative_to(docs.resolve()) or not path.is_relative_to(root.resolve()):
            return match.group(0)  # a page of the site (MkDocs checks it), or outside the repository
        relative = path.relative_to(root.resolve()).as_posix()
        if not path.exists():
            log.warning("%s links to %s, which is not in the repository", page_path, relative)
            return match.group(0)
        if label.startswith("!"):
            log.warning("%s shows the image %s from outside docs/: copy it to docs/images/", page_path, relative)
            return match.group(0)
        if repo_url:
            kind = "tree" if path.is_dir() else "blob"
            return f"{label}({repo_url.rstrip('/')}/{kind}/main/{relative}{'/' if path.is_dir() else ''})"
        return label[1:-1]  # the link's words, without the link

    return outside_code(markdown, lambda text: LINK.sub(resolved, text))


# -- MkDocs events -------------------------------------------------------------------------------------


def on_files(files, config):
    """Add the generated pages before the navigation is built."""
    from mkdocs.structure.files import File

    root = Path(config["config_file_path"]).parent
    files.append(File.generated(config, CLI_PAGE, content=cli_reference()))
    files.append(File.generated(config, BENCHMARKS_PAGE, content=benchmarks_page(root)))
    return files


def on_page_markdown(markdown, page, config, files):
    root = Path(config["config_file_path"]).parent
    return repository_links(markdown, page.file.src_uri, root, Path(config["docs_dir"]), config.get("repo_url"))
