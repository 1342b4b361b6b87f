"""The code blocks of the README and the documentation pages, and how each is checked (issue 49, item 3).

Every fenced ``bash``/``sh``/``console``/``python`` block of ``README.md`` and ``docs/**/*.md`` is checked
one of three ways, chosen by the HTML comment on the line right before its fence (invisible on GitHub
and on the site):

- no comment, or ``<!-- runs: NOTE -->``: the block runs, at tiny sizes, on a tiny run directory
  (``tiny_run.py``) that stands for ``runs/quick``. Shell lines that call ``worldagent`` run in-process
  (one Python, so JAX compiles each program once); other lines run in ``bash``. Options with large
  budgets are cut (``BUDGET_CUTS``), and a few commands get options that keep them small (``TINY_OPTIONS``). Python blocks run in one fresh namespace per page, in order.
- ``<!-- parses: REASON -->``: each ``worldagent`` command of the block is parsed by the command line
  itself, with the options as written (an unknown option, a missing argument or a bad value fails), but
  not run: for commands that take minutes even cut down.
- ``<!-- illustrative: REASON -->``: not run (a server, a cluster, a placeholder, hours of training).

In every block the repository files it names (a script under ``benchmarks/``, ``examples/...``) must exist, and a
``runs``/``parses`` comment may name replacements made before it runs: ``"gen/racing" -> "runs/quick/racing/generator"``.
A fenced ``text`` block right after a block that runs is the output it prints: numbers may differ (the tiny run
is not the run the page quotes), words may not; a line ``...`` stands for any lines.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CODE_LANGUAGES = {"bash": "shell", "sh": "shell", "console": "shell", "shell": "shell", "python": "python", "py": "python"}
KINDS = ("runs", "parses", "illustrative")
FENCE = re.compile(r"^(?P<indent> *)(?P<fence>```+|~~~+)\s*(?P<lang>[\w+-]*)")
MARKER = re.compile(r"^\s*<!--\s*(?P<kind>[a-z-]+):\s*(?P<note>.*?)\s*-->\s*$")
REPLACEMENT = re.compile(r'"([^"]+)"\s*->\s*"([^"]*)"')
# A file of the repository a command names (a script, an example package); output paths live under runs/.
REPOSITORY_FILE = re.compile(r"(?<![\w./-])((?:benchmarks|examples|tests|src|docs)/[\w./-]*[\w/])")
# Options whose values are budgets: cut to these at most when a block runs (a run of 1,000 worlds takes minutes).
BUDGET_CUTS = {
    "--worlds": 8,
    "--budget": 21,
    "--episodes": 16,
    "--repeats": 2,
    "--candidates": 8,
    "--eval-worlds": 4,
    "--n": 16,
}
COMMAND_CUTS: dict[str, dict[str, int]] = {}  # a command's own cuts, over BUDGET_CUTS
# Options added to a command that does not give them: an atlas's grid needs a world per cell (4 x 4 fit in one
# generation of 21), and replaying each elite on 32 fresh episodes is most of a small atlas's time.
TINY_OPTIONS = {"atlas": {"--cells": "4", "--confirm": "2"}}
QUICK_RUN = "runs/quick"
MIN_REASON_WORDS = 3


@dataclass(frozen=True)
class Block:
    """One fenced code block of a page."""

    page: str  # relative to the repository, e.g. "docs/atlas.md"
    line: int  # of the opening fence, 1-based
    language: str  # "shell" or "python"
    code: str
    kind: str  # runs, parses or illustrative
    note: str = ""  # the marker's reason or note
    output: str | None = None  # the text block printed right after it, if any
    replacements: tuple[tuple[str, str], ...] = field(default=())

    @property
    def id(self) -> str:
        return f"{self.page}:{self.line}"


def pages(root: Path = ROOT) -> list[Path]:
    """The README and every page of the site's sources."""
    return [root / "README.md", *sorted((root / "docs").rglob("*.md"))]


def fenced(lines: list[str]) -> list[tuple[int, str, list[str]]]:
    """(index of the opening fence, its language, its lines) of each fenced block, in order."""
    found, index = [], 0
    while index < len(lines):
        match = FENCE.match(lines[index])
        if not match:
            index += 1
            continue
        close = re.compile(rf"^ *{re.escape(match['fence'][0])}{{{len(match['fence'])},}}\s*$")
        end = next((j for j in range(index + 1, len(lines)) if close.match(lines[j])), len(lines))
        indent = len(match["indent"])
        found.append((index, match["lang"].lower(), [line[indent:] for line in lines[index + 1 : end]]))
        index = end + 1
    return found


def marker(line: str) -> tuple[str, str] | None:
    """``(kind, note)`` of a ``<!-- kind: note -->`` line, None for any other line."""
    match = MARKER.match(line)
    return (match["kind"], match["note"]) if match else None


def blocks_of(text: str, page: str) -> list[Block]:
    """The shell and Python blocks of one page, each with its marker and the output printed after it."""
    lines = text.split("\n")
    found = fenced(lines)
    blocks = []
    for position, (index, language, body) in enumerate(found):
        if language not in CODE_LANGUAGES:
            continue
        kind, note = (marker(lines[index - 1]) if index > 0 else None) or ("runs", "")
        if language == "console":  # `$ command` lines; the others are what it prints
            printed = [line for line in body if not line.startswith("$ ")]
            body = [line[2:] for line in body if line.startswith("$ ")]
        blocks.append(
            Block(
                page=page,
                line=index + 1,
                language=CODE_LANGUAGES[language],
                code="\n".join(body),
                kind=kind,
                note=note,
                output="\n".join(printed) if language == "console" and any(printed) else printed_after(lines, found, position),
                replacements=tuple(REPLACEMENT.findall(note)) if kind != "illustrative" else (),
            )
        )
    return blocks


def printed_after(lines: list[str], found, position: int) -> str | None:
    """The body of a ``text`` block that follows block ``position`` with only blank lines between."""
    if position + 1 >= len(found):
        return None
    index, _, body = found[position]
    end = index + 1 + len(body)  # the closing fence
    following, language, text = found[position + 1]
    between = lines[end + 1 : following]
    return "\n".join(text) if language == "text" and not any(line.strip() for line in between) else None


def all_blocks(root: Path = ROOT) -> list[Block]:
    return [block for path in pages(root) for block in blocks_of(path.read_text(), path.relative_to(root).as_posix())]


def marker_problem(block: Block) -> str | None:
    """Why a block's marker is not acceptable (an illustrative block must say why), or None."""
    if block.kind not in KINDS:
        return f"{block.id}: unknown marker <!-- {block.kind}: -->; use one of {', '.join(KINDS)}"
    if block.kind in ("illustrative", "parses") and len(block.note.split()) < MIN_REASON_WORDS:
        return f"{block.id}: say why in its marker, e.g. <!-- {block.kind}: trains for minutes -->"
    return None


def missing_files(code: str, root: Path = ROOT) -> list[str]:
    """Repository files a block names that do not exist."""
    names = {match.rstrip("/.") for match in REPOSITORY_FILE.findall(code)}
    return sorted(name for name in names if not (root / name).exists())


# -- rewriting a block to run at tiny sizes -----------------------------------------------------------------


def prepared(code: str, replacements, run_dir: Path) -> str:
    """The block's code with its marker's replacements made, then ``runs/quick`` pointed at the tiny run."""
    for old, new in replacements:
        if old not in code:
            raise AssertionError(f"the marker replaces {old!r}, which the block does not contain")
        code = code.replace(old, new)
    return re.sub(rf"(?<![\w./-]){re.escape(QUICK_RUN)}(?![\w-])", str(run_dir), code)


def logical_lines(code: str) -> list[str]:
    """Shell lines with ``\\`` continuations joined; a heredoc stays one unit with its body."""
    units, lines, index = [], code.split("\n"), 0
    while index < len(lines):
        line = lines[index]
        while line.endswith("\\") and index + 1 < len(lines):
            index += 1
            line = line[:-1] + " " + lines[index].lstrip()
        heredoc = re.search(r"<<-?\s*'?\"?(\w+)", line)
        if heredoc:
            end = next((j for j in range(index + 1, len(lines)) if lines[j].strip() == heredoc.group(1)), len(lines) - 1)
            line = "\n".join([line, *lines[index + 1 : end + 1]])
            index = end
        if line.strip() and not line.lstrip().startswith("#"):
            units.append(line)
        index += 1
    return units


def worldagent_argv(line: str) -> list[str] | None:
    """The arguments of a ``worldagent ...`` line (comments dropped), None for any other command."""
    if "<<" in line:
        return None
    words = shlex.split(line, comments=True)
    return words[1:] if words and words[0] == "worldagent" else None


def cut_budgets(argv: list[str]) -> list[str]:
    """``argv`` (a ``worldagent`` command's words) with each budget option's integer value cut to
    ``BUDGET_CUTS`` (or the command's ``COMMAND_CUTS``) at most, and the command's ``TINY_OPTIONS`` it lacks."""
    command = argv[0] if argv else ""
    cuts = BUDGET_CUTS | COMMAND_CUTS.get(command, {})
    cut = list(argv)
    for index, word in enumerate(cut[:-1]):
        if word in cuts and cut[index + 1].isdigit():
            cut[index + 1] = str(min(int(cut[index + 1]), cuts[word]))
    for option, value in TINY_OPTIONS.get(command, {}).items():
        if option not in cut:
            cut += [option, value]
    return cut


# -- checking printed output ----------------------------------------------------------------------------------

NUMBER = r"-?(?:\d[\d,]*(?:\.\d+)?|\.\d+)(?:e[-+]?\d+)?|\bnan\b|\binf\b|n/a"


def output_pattern(expected: str) -> re.Pattern:
    """A pattern for printed output like ``expected``: its words as written, any number where it shows one,
    any whitespace where it has some, any lines where it has a line ``...``."""
    chunks = re.split(r"^\s*\.\.\.\s*$", expected.strip(), flags=re.MULTILINE)
    return re.compile(r"[\s\S]*?".join(chunk_pattern(chunk.strip()) for chunk in chunks), re.IGNORECASE)


def chunk_pattern(chunk: str) -> str:
    parts = []
    for token in re.split(r"(\s+)", chunk):
        if not token:
            continue
        if token.isspace():
            parts.append(r"\s+")
            continue
        pieces = re.split(rf"({NUMBER})", token)
        parts.append("".join(f"(?:{NUMBER})" if i % 2 else re.escape(piece) for i, piece in enumerate(pieces)))
    return "".join(parts)


def output_problem(expected: str, printed: str) -> str | None:
    """Why ``printed`` is not the output the page shows, or None."""
    if output_pattern(expected).search(printed):
        return None
    return f"the page shows\n{expected}\nbut the block printed\n{printed}"
