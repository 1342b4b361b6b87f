"""The event language: which evaluated worlds have a property (paper §6.2), shared by every command.

``--select`` (influence), ``--event`` (failure-rate), ``--failure`` and ``--target`` (curricula)
all read their text here. It lives beside the registry, below search, analysis, training and
influence, so that none of them imports another to read an event.

The paper forms its influenced training distributions from worlds with a property: racing
worlds where the agent is likely to crash ("crash rate > 0.5", §6.2.1), harvest worlds where
nobody is tagged out in an entire episode ("conflict == 0", §6.2.2). A selection is that
property written as text and parsed by a small grammar, never by ``eval``::

    selection := clause ("and" clause)*
    clause    := METRIC OP NUMBER
    OP        := "<" | "<=" | ">" | ">=" | "==" | "!="

``METRIC`` is one of the env's per-episode metrics (``EnvSpec.metrics.names``), compared
after averaging it over a world's episodes (so ``crashed`` is the world's crash rate), or an
alias the env registers (racing: ``crash_rate`` for ``crashed``, ``lap_rate`` for
``lap_completed``), or ``reward``, every env's main metric (racing ``return``, harvest
``group_reward``).
``==`` and ``!=`` compare with a tolerance of 1e-9 so that means of exact values (a rate of
k/8) are not lost to float rounding.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from worldagent.envs import registry
from worldagent.errors import WorldagentError

OPERATORS = ("<", "<=", ">", ">=", "==", "!=")
EQUALITY_TOLERANCE = 1e-9

EXAMPLE = "e.g. 'crash_rate > 0.5' or 'conflict == 0 and equality >= 0.5'"

_TOKEN = re.compile(
    r"\s*(?:(?P<number>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)"
    r"|(?P<name>[A-Za-z_][A-Za-z0-9_]*)"
    r"|(?P<op>[<>=!]+)"
    r"|(?P<other>\S))"
)


@dataclass(frozen=True)
class Clause:
    """``metric op number``: ``name`` as written, ``metric`` the env's name for it (None while an
    env-dependent alias such as ``reward`` is unresolved)."""

    name: str
    op: str
    number: float
    metric: str | None

    def holds(self, values: np.ndarray) -> np.ndarray:
        """bool[n]: which per-world means ``values`` f64[n] satisfy the clause (NaN never does)."""
        values = np.asarray(values, np.float64)
        close = np.isclose(values, self.number, rtol=EQUALITY_TOLERANCE, atol=EQUALITY_TOLERANCE)
        result = {
            "<": values < self.number,
            "<=": (values <= self.number) | close,
            ">": values > self.number,
            ">=": (values >= self.number) | close,
            "==": close,
            "!=": ~close,
        }[self.op]
        return result & np.isfinite(values)

    def describe(self) -> str:
        shown = self.name if self.metric in (None, self.name) else f"{self.name} ({self.metric})"
        return f"{shown} {self.op} {self.number:g}"


@dataclass(frozen=True)
class Selection:
    """A parsed selection: the clauses, all of which a world must satisfy.

    Attributes:
        text: the text it was parsed from.
        clauses: the ``Clause`` s, in order.
        env: the env its metric names were resolved for, or None.
    """

    text: str
    clauses: tuple[Clause, ...]
    env: str | None = None

    @property
    def metrics(self) -> tuple[str, ...]:
        """The distinct metrics the selection reads, in order (resolved names)."""
        return tuple(dict.fromkeys(clause.metric or clause.name for clause in self.clauses))

    def resolve(self, env: str) -> Selection:
        """The same selection with every name resolved for ``env`` (refuses other envs' metrics)."""
        return replace(self, clauses=tuple(_clause(c.name, c.op, c.number, env) for c in self.clauses), env=env)

    def describe(self) -> str:
        """A human-readable form for reports, with aliases spelled out: ``crash_rate (crashed) > 0.5``."""
        return " and ".join(clause.describe() for clause in self.clauses)

    def world_means(self, evaluations: Sequence) -> dict[str, np.ndarray]:
        """{metric: f64[n]} each selected metric averaged over each evaluation's episodes."""
        selection = self._for(evaluations)
        return {metric: world_means(evaluations, metric) for metric in selection.metrics}

    def mask(self, evaluations: Sequence) -> np.ndarray:
        """bool[n]: which evaluated worlds (``store.Evaluation`` s) have the property."""
        selection = self._for(evaluations)
        keep = np.ones(len(evaluations), bool)
        for clause in selection.clauses:
            keep &= clause.holds(world_means(evaluations, clause.metric))
        return keep

    def _for(self, evaluations: Sequence) -> Selection:
        """Resolved for the env whose metrics the evaluations hold (unless already resolved)."""
        if self.env is not None or all(c.metric is not None for c in self.clauses):
            return self
        return self.resolve(infer_env(evaluations))


def world_means(evaluations: Sequence, metric: str) -> np.ndarray:
    """f64[n]: ``metric`` averaged over each evaluation's episodes (NaN where it has none)."""
    means = np.full(len(evaluations), np.nan)
    for i, evaluation in enumerate(evaluations):
        values = [episode[metric] for episode in evaluation.episodes if episode.get(metric) is not None]
        if values:
            means[i] = float(np.mean(np.asarray(values, np.float64)))
    return means


def aliases(env: str) -> dict[str, str]:
    """alias -> metric of ``env``: its registered aliases, and ``reward`` for its main metric."""
    metrics = registry.get(env).metrics
    return {**metrics.aliases, "reward": metrics.main}


def infer_env(evaluations: Sequence) -> str:
    """The env whose metrics the evaluations' episodes hold (the registered env most of whose metrics are there)."""
    keys = set().union(*(episode.keys() for evaluation in evaluations for episode in evaluation.episodes))
    overlap = {name: len(keys & set(registry.get(name).metrics.names)) for name in registry.names() if registry.get(name).metrics.main in keys}
    if not overlap:
        raise WorldagentError("cannot tell the environment from these evaluations' metrics; resolve the selection with .resolve(env).")
    return max(overlap, key=overlap.get)


def valid_names(env: str | None = None) -> list[str]:
    """The metric names and aliases a selection may use (for ``env``, or for any registered env)."""
    envs = [registry.get(env).name] if env else list(registry.names())
    return list(dict.fromkeys(name for e in envs for name in (*registry.get(e).metrics.names, *aliases(e))))


def _alias_target(name: str, env: str | None) -> str | None:
    """What alias ``name`` means for ``env``; without an env, its meaning if every env agrees, else None."""
    if env is not None:
        return aliases(env).get(name, name)
    meanings = {aliases(e)[name] for e in registry.names() if name in aliases(e)}
    return meanings.pop() if len(meanings) == 1 else (None if meanings else name)


def _clause(name: str, op: str, number: float, env: str | None) -> Clause:
    """A checked clause; the name resolved when ``env`` (or the alias) makes it unambiguous."""
    if name not in valid_names(env):
        where = f"{registry.get(env).name} " if env else ""
        raise WorldagentError(f"unknown {where}metric {name!r} in the selection; use one of: {', '.join(valid_names(env))}.")
    return Clause(name, op, number, _alias_target(name, env))


def _tokens(text: str) -> list[tuple[str, str, int]]:
    """(kind, text, position) of each token: number, name, op; anything else is refused."""
    tokens, position = [], 0
    while position < len(text):
        match = _TOKEN.match(text, position)
        if match is None:  # only trailing whitespace is left
            break
        kind = match.lastgroup
        value = match.group(kind)
        start = match.start(kind)
        if kind == "other":
            raise WorldagentError(
                f"unexpected {value!r} at character {start + 1} of the selection; write METRIC OP NUMBER joined by 'and', {EXAMPLE}."
            )
        tokens.append((kind, value, start))
        position = match.end()
    return tokens


def parse_selection(text: str, env: str | None = None) -> Selection:
    """Parse a selection such as ``"crash_rate > 0.5"`` (grammar in the module docstring).

    Args:
        text: the selection.
        env: a registered env's name to check and resolve metric names for it; None accepts
            any registered env's metrics and resolves env-dependent aliases (``reward``) when the
            selection is applied.

    Returns:
        A ``Selection``.

    Raises:
        WorldagentError: one line naming the fix, for empty text, an unknown metric (listing the
            valid ones), a bad operator, a missing or non-finite number, or trailing junk.
    """
    if not isinstance(text, str) or not text.strip():
        raise WorldagentError(f"the selection is empty; write METRIC OP NUMBER, {EXAMPLE}.")
    tokens = _tokens(text)
    clauses, i = [], 0
    while True:
        clause, i = _parse_clause(tokens, i, env)
        clauses.append(clause)
        if i == len(tokens):
            return Selection(text.strip(), tuple(clauses), env)
        kind, value, start = tokens[i]
        if not (kind == "name" and value.lower() == "and"):
            raise WorldagentError(f"unexpected {value!r} at character {start + 1} after '{clause.describe()}'; join clauses with 'and', {EXAMPLE}.")
        if i + 1 == len(tokens):
            raise WorldagentError("the selection ends with 'and'; add another METRIC OP NUMBER clause or remove it.")
        i += 1


def _parse_clause(tokens: list, i: int, env: str | None) -> tuple[Clause, int]:
    """One ``METRIC OP NUMBER`` clause starting at token ``i``; returns it and the next index."""
    kind, value, start = tokens[i]
    if kind != "name" or value.lower() == "and":
        raise WorldagentError(f"expected a metric name at character {start + 1}, got {value!r}; write METRIC OP NUMBER, {EXAMPLE}.")
    name = value
    if i + 1 == len(tokens) or tokens[i + 1][0] != "op":
        got = f"got {tokens[i + 1][1]!r}" if i + 1 < len(tokens) else "the selection ends"
        raise WorldagentError(f"expected an operator ({' '.join(OPERATORS)}) after {name!r}, {got}; {EXAMPLE}.")
    op = tokens[i + 1][1]
    if op not in OPERATORS:
        raise WorldagentError(f"bad operator {op!r} after {name!r}; use one of {' '.join(OPERATORS)}.")
    if i + 2 == len(tokens) or tokens[i + 2][0] != "number":
        got = f"got {tokens[i + 2][1]!r}" if i + 2 < len(tokens) else "the selection ends"
        raise WorldagentError(f"missing number after '{name} {op}' ({got}); write a number such as 0.5 or -100.")
    number = float(tokens[i + 2][1])
    if not np.isfinite(number):
        raise WorldagentError(f"the number after '{name} {op}' is not finite; write a finite number.")
    return _clause(name, op, number, env), i + 3
