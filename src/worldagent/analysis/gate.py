"""The ``--fail-if`` language of ``worldagent diff``: when a new agent B is worse enough than A to stop a pipeline.

A gate is one or more conditions; the gate fails (exit code 1) when any of them holds::

    gate      := condition ("or" condition)*
    condition := QUANTITY OP NUMBER          OP: < <= > >= == !=
    QUANTITY  := BASE | BASE "_low" | BASE "_high"

The bases, each a number ``worldagent diff`` reports (B is the new agent, A the old one):

- ``p_failure_increase``: P_B(failure) − P_A(failure) over the compared worlds;
  ``p_failure_a``, ``p_failure_b``: each one's P(failure);
- ``regressed``, ``improved``: worlds that fail under B and pass under A, and the reverse;
- ``METRIC_drop`` (mean of A − B) and ``METRIC_increase`` (B − A) for any metric of the env or
  alias (``reward_drop``, ``return_drop``, ``crash_rate_increase``);
- ``cvar_drop``: α-CVaR of A − α-CVaR of B (the worst 10% of worlds, of ``--metric``);
- ``search_regressed``: distinct regressed worlds the differential search found, confirmed (B's
  confirmed failure and A's confirmed pass on the same fresh episodes; found, when ``--confirm 0``);
  ``search_drop``: the drop of the search's objective (A − B, in the direction searched) on its most
  extreme world, confirmed likewise. The search keeps the worst of many noisy scores, so its found
  figures are biased; the world-set quantities above are not (every sampled world counts) and are
  read as measured.

``_low`` / ``_high`` read the 95% interval's bounds instead of the estimate (of
``p_failure_increase``, ``METRIC_drop``/``_increase``, ``cvar_drop``): ``return_drop_low > 0``
fails only when the drop is significant. Text is tokenised by a regular expression, never
``eval``'d; a quantity that could not be computed (NaN) fails the gate, so a broken
comparison never passes a pipeline.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from worldagent.errors import WorldagentError
from worldagent.events import OPERATORS

COUNTS = ("regressed", "improved", "p_failure_a", "p_failure_b")
WITH_INTERVAL = ("p_failure_increase", "cvar_drop")
SEARCH = ("search_regressed", "search_drop")
_TOKEN = re.compile(r"\s*(?:(?P<number>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)|(?P<name>[A-Za-z_]\w*)|(?P<op>[<>=!]+)|(?P<other>\S))")
EXAMPLE = "e.g. 'p_failure_increase > 0.005', 'regressed > 0' or 'return_drop > 2 or regressed > 3'"


@dataclass(frozen=True)
class Condition:
    """``quantity op number``; ``quantity`` canonical (aliases resolved, e.g. ``crashed_increase``)."""

    quantity: str
    op: str
    number: float
    text: str

    def holds(self, value: float) -> bool:
        """Whether ``value`` trips the condition (NaN always does: a gate never passes what it could not check)."""
        if value is None or not np.isfinite(value):
            return True
        return bool({"<": value < self.number, "<=": value <= self.number, ">": value > self.number,
                     ">=": value >= self.number, "==": value == self.number, "!=": value != self.number}[self.op])  # fmt: skip


@dataclass(frozen=True)
class Gate:
    """Parsed ``--fail-if`` texts: every condition of every text (any one holding fails the gate)."""

    conditions: tuple[Condition, ...]

    @property
    def quantities(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(c.quantity for c in self.conditions))

    @property
    def needs_search(self) -> bool:
        return any(base(c.quantity) in SEARCH for c in self.conditions)

    @property
    def needs_worlds(self) -> bool:
        return any(base(c.quantity) not in SEARCH for c in self.conditions)

    def check(self, values: Mapping[str, float]) -> dict:
        """{"failed": bool, "conditions": [{"condition", "value", "holds"}]} of ``values`` {quantity: number}."""
        rows = []
        for condition in self.conditions:
            value = values.get(condition.quantity)
            value = None if value is None else float(value)
            rows.append({"condition": condition.text, "value": value, "holds": condition.holds(value)})
        return {"failed": any(row["holds"] for row in rows), "conditions": rows}


def base(quantity: str) -> str:
    """``return_drop_low`` -> ``return_drop``."""
    for suffix in ("_low", "_high"):
        if quantity.endswith(suffix):
            return quantity[: -len(suffix)]
    return quantity


def canonical_quantity(name: str, metrics) -> str:
    """The canonical quantity ``name`` means, with ``metrics`` an env's ``registry.Metrics``; refused in one line."""
    stem, suffix = base(name), name[len(base(name)) :]
    if stem in COUNTS or stem in SEARCH:
        if suffix:
            raise WorldagentError(f"{name!r}: {stem} has no interval; use {stem} alone ({EXAMPLE}).")
        return stem
    if stem in WITH_INTERVAL:
        return name
    for change in ("_drop", "_increase"):
        if stem.endswith(change):
            metric = stem[: -len(change)]
            aliases = {**metrics.aliases, "reward": metrics.main}
            if metric in metrics.names or metric in aliases:
                return f"{aliases.get(metric, metric)}{change}{suffix}"
            raise WorldagentError(f"{name!r}: unknown metric {metric!r}; use one of: {', '.join((*metrics.names, *aliases))}.")
    known = ", ".join((*COUNTS, *WITH_INTERVAL, "METRIC_drop", "METRIC_increase", *SEARCH))
    raise WorldagentError(f"unknown quantity {name!r} in --fail-if; use one of: {known} (optionally _low/_high), {EXAMPLE}.")


def parse_gate(texts: Sequence[str], metrics) -> Gate:
    """Parse ``--fail-if`` texts (grammar in the module docstring) for an env's ``registry.Metrics``.

    Raises:
        WorldagentError: one line naming the fix (an unknown quantity, a bad operator, a missing number, junk).
    """
    conditions = []
    for text in texts:
        if not isinstance(text, str) or not text.strip():
            raise WorldagentError(f"--fail-if is empty; write QUANTITY OP NUMBER, {EXAMPLE}.")
        tokens, i = _tokens_of(text), 0
        while True:
            if i + 3 > len(tokens) or [kind for kind, _ in tokens[i : i + 3]] != ["name", "op", "number"]:
                where = tokens[i][1] if i < len(tokens) else "the end"
                raise WorldagentError(f"--fail-if {text!r}: expected QUANTITY OP NUMBER at {where!r}; {EXAMPLE}.")
            name, op, number = tokens[i][1], tokens[i + 1][1], float(tokens[i + 2][1])
            if op not in OPERATORS:
                raise WorldagentError(f"--fail-if {text!r}: bad operator {op!r}; use one of {' '.join(OPERATORS)}.")
            conditions.append(Condition(canonical_quantity(name, metrics), op, number, f"{name} {op} {tokens[i + 2][1]}"))
            i += 3
            if i == len(tokens):
                break
            if tokens[i][1].lower() != "or" or i + 1 == len(tokens):
                raise WorldagentError(f"--fail-if {text!r}: join conditions with 'or' (several --fail-if also join with or); {EXAMPLE}.")
            i += 1
    return Gate(tuple(conditions))


def _tokens_of(text: str) -> list[tuple[str, str]]:
    """(kind, text) of each token: number, name or op; anything else is refused."""
    tokens = []
    for match in _TOKEN.finditer(text):
        kind = match.lastgroup
        if kind == "other":
            raise WorldagentError(f"--fail-if {text!r}: unexpected {match.group(kind)!r} at character {match.start(kind) + 1}; {EXAMPLE}.")
        tokens.append((kind, match.group(kind)))
    return tokens


def quantities(result: Mapping) -> dict[str, float]:
    """{quantity: value} of a ``worldagent diff`` result (``differential.diff_result``): every base and bound the gate reads."""
    values: dict[str, float] = {}
    paired = result.get("worlds")
    if paired:
        failure = paired["failure"]
        difference = failure["difference"]
        values |= {"regressed": failure["regressed"], "improved": failure["improved"]}
        values |= {"p_failure_a": failure["a"]["p"], "p_failure_b": failure["b"]["p"]}
        values |= _with_bounds("p_failure_increase", difference["value"], difference["low"], difference["high"])
        for metric, row in paired["metrics"].items():
            values |= _with_bounds(f"{metric}_increase", row["difference"], row["low"], row["high"])
            values |= _with_bounds(f"{metric}_drop", -row["difference"], -row["high"], -row["low"])
        risk = paired["cvar"]
        values |= _with_bounds("cvar_drop", -risk["difference"], -risk["high"], -risk["low"])
    search = result.get("search")
    if search:
        # a search's worlds are a selection: its figures gate on their confirmation (both agents, fresh episodes) when run
        confirmed = search.get("confirmed")
        if confirmed:
            values |= {"search_regressed": confirmed["regressed"], "search_drop": confirmed["largest_drop"]["mean"]}
        else:
            values |= {"search_regressed": search["regressed"], "search_drop": search["largest_drop"]}
    return values


def _with_bounds(name: str, value: float, low: float, high: float) -> dict[str, float]:
    return {name: value, f"{name}_low": low, f"{name}_high": high}
