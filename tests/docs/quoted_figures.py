"""Figures quoted in prose, each followed by the result file that recorded it (issue 49, item 3).

A figure carries ``<!-- from: FILE KEY -->`` right after it (and its unit): FILE a JSON of the repository, KEY a
dotted path into it (``seconds``, ``racing_steps_per_s.4096``) where ``*`` matches every key of a level and the
matches are summed (``phases.racing/*.wall_s``: an env's phases), or ``+`` sums whole keys (no brackets: the
site's cross-reference check reads ``[..][..]`` as a link even in a comment), then an optional ``/N`` or ``xN`` that scales
the value to the unit the prose uses (``/60``: seconds as minutes). The figure is the last number before the
comment on its line (``33½`` reads 33.5, ``−0.02`` and ``-0.02`` are negative); it must equal the recorded value to the precision it is written with.
The comment is invisible on GitHub and on the site, so the prose reads as before.
"""

from __future__ import annotations

import fnmatch
import json
import re
from dataclasses import dataclass
from pathlib import Path

FROM = re.compile(r"<!--\s*from:\s*(?P<file>\S+)\s+(?P<key>\S+)(?:\s+(?P<op>[/x])(?P<factor>[\d.e+]+))?\s*-->")
FIGURE = re.compile(r"([−-]?\d[\d,]*(?:\.\d+)?)(½)?(?!.*\d)")  # a minus sign (− or -) is the figure's


@dataclass(frozen=True)
class Quote:
    page: str
    line: int
    shown: str  # as written, e.g. "33½", "3.46"
    file: str
    key: str
    scale: float


def quotes_of(text: str, page: str) -> list[Quote]:
    """Every figure marked with its result file on one page."""
    quotes = []
    for number, line in enumerate(text.split("\n"), 1):
        position = 0
        for match in FROM.finditer(line):
            before = FROM.sub("", line[position : match.start()])
            figure = FIGURE.search(before)
            position = match.end()
            scale = float(match["factor"]) if match["op"] else 1.0
            quotes.append(
                Quote(page, number, figure.group(0) if figure else "", match["file"], match["key"], 1 / scale if match["op"] == "/" else scale)
            )
    return quotes


def recorded(data, key: str) -> float:
    """The value at a dotted ``key`` of ``data``; ``*`` (or any glob) at a level sums over its matches, ``+`` sums keys."""
    if "+" in key:
        return sum(recorded(data, part) for part in key.split("+"))
    values = [data]
    for part in key.split("."):
        found = []
        for value in values:
            if isinstance(value, list):
                value = {str(index): item for index, item in enumerate(value)}
            if not isinstance(value, dict):
                continue
            found += [value[name] for name in value if fnmatch.fnmatchcase(name, part)]
        values = found
    if not values or not all(isinstance(value, int | float) for value in values):
        raise KeyError(f"{key} names no number")
    return float(sum(values))


def shown_value(shown: str) -> tuple[float, float]:
    """(the figure, half a unit of its last written digit: how far the recorded value may be from it)."""
    half = shown.endswith("½")
    digits = shown.removesuffix("½").replace(",", "").replace("−", "-")
    decimals = len(digits.partition(".")[2])
    return float(digits) + (0.5 if half else 0.0), (0.25 if half else 0.5 * 10**-decimals)


def quote_problem(quote: Quote, root: Path) -> str | None:
    """Why a quoted figure does not match its result file, or None."""
    where = f"{quote.page}:{quote.line}"
    if not quote.shown:
        return f"{where}: no figure before <!-- from: {quote.file} {quote.key} -->"
    path = root / quote.file
    if not path.is_file():
        return f"{where}: {quote.file} is not in the repository"
    try:
        value = recorded(json.loads(path.read_text()), quote.key) * quote.scale
    except KeyError as error:
        return f"{where}: {quote.file}: {error.args[0]}"
    figure, tolerance = shown_value(quote.shown)
    if abs(value - figure) > tolerance + 1e-9:
        return f"{where}: the page says {quote.shown}, {quote.file} {quote.key} records {value:.6g}"
    return None
