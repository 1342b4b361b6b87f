"""The environment contract's conformance checks, shipped in the package (DESIGN.md "Check").

``worldagent check ENV [--generator DIR]`` runs them from an installed worldagent: no clone, no test extras.
Each check is a plain function ``check(subject) -> Result`` (``conformance.checks``, ``conformance.declared``);
``tests/envs/test_conformance.py`` calls the same functions. ``run`` plays them on the procedural generator's
worlds and, given a generator, the world-level ones again on worlds G(z) decoded from prior latents: the worlds
every search, atlas and explorer sees (a descriptor can vary over generated worlds and be constant after repair)::

    from worldagent import conformance

    for row in conformance.run(registry.get("racing")):
        print(row.worlds, row.result.status, row.result.name, row.result.reason)

This package sits above ``envs/`` (it reads the repair, the event language, the pictures and the algorithms), so
``envs/`` keeps importing nothing above it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from worldagent.conformance import checks, declared
from worldagent.conformance.checks import FAIL, PASS, SKIP, Result, one_line
from worldagent.conformance.subject import DECODED, GENERATED, Subject, decoded_subject, generated_subject
from worldagent.envs.registry import EnvSpec

__all__ = ["DECODED_CHECKS", "GENERATED_CHECKS", "FAIL", "PASS", "SKIP", "Result", "Row", "Subject", "run", "decoded_subject", "generated_subject"]

# Every check, on the procedural generator's worlds.
GENERATED_CHECKS = (
    checks.generator_deterministic,
    checks.reset_and_step,
    checks.same_key,
    checks.truncation,
    checks.autoreset,
    checks.store_round_trip,
    checks.malformed_refused,
    checks.cells_binary,
    declared.metrics_declared,
    declared.scripted_policies,
    declared.repair_valid,
    declared.declared_usable,
    declared.flat_observation,
    checks.descriptors_vary,
    checks.episode_pictures,
    declared.failure_usable,
    declared.world_sets_valid,
)
# The checks of worlds themselves, again on G(z)'s: the repair's worlds must play, store and describe as generated ones do.
DECODED_CHECKS = (
    checks.decoded_valid,
    checks.reset_and_step,
    checks.same_key,
    checks.truncation,
    checks.autoreset,
    checks.store_round_trip,
    checks.cells_binary,
    checks.descriptors_vary,
    checks.episode_pictures,
)


@dataclass(frozen=True)
class Row:
    """One line of the table: which worlds (``GENERATED`` or ``DECODED``) and the check's ``Result``."""

    worlds: str
    result: Result


def planned(generator: Any = None) -> int:
    """How many checks ``run`` plays (the progress bar's total)."""
    return len(GENERATED_CHECKS) + (len(DECODED_CHECKS) if generator is not None else 0)


def run(spec: EnvSpec, generator: Any = None, advance: Callable[..., None] | None = None) -> list[Row]:
    """Every check on ``spec``'s generated worlds, and (given ``generator``, a ``Generator`` of ``spec``'s worlds) the
    world-level ones on decoded worlds. A subject that cannot be built fails one row and skips its checks.

    Args:
        spec: the environment.
        generator: G(z), or None.
        advance: called after each check (a progress bar's ``advance``).

    Returns:
        The rows in order: generated worlds' first.
    """
    advance = advance or (lambda steps=1, **fields: None)
    rows = []
    subjects = [(GENERATED, lambda: generated_subject(spec), GENERATED_CHECKS)]
    if generator is not None:
        subjects.append((DECODED, lambda: decoded_subject(spec, generator), DECODED_CHECKS))
    for kind, build, chosen in subjects:
        subject, failure = built(kind, build)
        if failure is not None:
            rows.append(Row(kind, failure))
            advance(len(chosen))
            continue
        for one in chosen:
            rows.append(Row(kind, one(subject)))
            advance()
    return rows


def built(kind: str, build: Callable[[], Subject]) -> tuple[Subject | None, Result | None]:
    """(the subject, None), or (None, a failed ``Result`` saying why its worlds or env could not be made)."""
    try:
        return build(), None
    except Exception as error:  # noqa: BLE001 - reported as the failed row, not a traceback
        return None, Result(f"{kind} worlds and the env can be made", FAIL, one_line(f"{type(error).__name__}: {error}")[:300], error)


def table(rows: Sequence[Row]) -> list[str]:
    """The rows as aligned text lines (worlds, check, result, reason), a header first and a count last."""
    header = ("worlds", "check", "result", "reason")
    cells = [header, *((row.worlds, row.result.name, row.result.status, row.result.reason) for row in rows)]
    widths = [max(len(line[i]) for line in cells) for i in range(3)]
    lines = ["  ".join(value.ljust(width) for value, width in zip(line[:3], widths)) + "  " + line[3] for line in cells]
    counts = {status: sum(row.result.status == status for row in rows) for status in (PASS, FAIL, SKIP)}
    lines.append(f"{len(rows)} checks: {counts[PASS]} passed, {counts[FAIL]} failed, {counts[SKIP]} skipped")
    return lines
