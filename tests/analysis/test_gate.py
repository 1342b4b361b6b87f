"""The --fail-if language of ``worldagent diff`` (analysis.gate): parsing, one-line refusals, and checking a result."""

from __future__ import annotations

import math

import pytest

from worldagent.analysis.gate import parse_gate, quantities
from worldagent.envs import registry
from worldagent.errors import WorldagentError

METRICS = registry.get("racing").metrics


def result(regressed=2, improved=0, drop=-3.0, p_increase=0.02, p_low=0.001, search=None) -> dict:
    """A ``differential.diff`` result with the numbers the gate reads (B − A of the return: ``drop``)."""
    row = {"difference": drop, "low": drop - 1, "high": drop + 1}
    return {
        "worlds": {
            "failure": {
                "regressed": regressed,
                "improved": improved,
                "a": {"p": 0.1},
                "b": {"p": 0.1 + p_increase},
                "difference": {"value": p_increase, "low": p_low, "high": p_increase + 0.01},
            },
            "metrics": {"return": row, "crashed": {"difference": p_increase, "low": 0.0, "high": 0.05}},
            "cvar": {"difference": -40.0, "low": -60.0, "high": -20.0},
        },
        "search": search,
    }


def test_the_issues_three_gates_parse_and_decide():
    values = quantities(result())
    for text, fails in [("p_failure_increase > 0.005", True), ("regressed > 0", True), ("return_drop > 2", True), ("return_drop > 5", False)]:
        assert parse_gate([text], METRICS).check(values)["failed"] is fails, text
    passing = quantities(result(regressed=0, drop=0.0, p_increase=0.0, p_low=-0.01))
    gate = parse_gate(["p_failure_increase > 0.005", "regressed > 0", "return_drop > 2"], METRICS)
    assert gate.check(passing) == {
        "failed": False,
        "conditions": [
            {"condition": "p_failure_increase > 0.005", "value": 0.0, "holds": False},
            {"condition": "regressed > 0", "value": 0.0, "holds": False},
            {"condition": "return_drop > 2", "value": 0.0, "holds": False},
        ],
    }


def test_aliases_bounds_or_and_search_quantities():
    values = quantities(result(search={"regressed": 4, "largest_drop": 300.0}))
    assert values["return_drop"] == 3.0 and values["return_drop_low"] == 2.0 and values["return_drop_high"] == 4.0
    assert values["cvar_drop"] == 40.0 and values["cvar_drop_low"] == 20.0
    gate = parse_gate(["reward_drop_low > 2.5 or crash_rate_increase >= 0.02", "search_regressed > 3"], METRICS)
    assert gate.quantities == ("return_drop_low", "crashed_increase", "search_regressed")
    assert gate.needs_search and gate.needs_worlds
    rows = gate.check(values)["conditions"]
    assert [r["holds"] for r in rows] == [False, True, True]
    assert not parse_gate(["search_drop > 1"], METRICS).needs_worlds


def test_a_quantity_that_could_not_be_computed_fails_the_gate():
    values = quantities(result())
    values["return_drop_low"] = math.nan
    assert parse_gate(["return_drop_low > 100"], METRICS).check(values)["failed"]
    assert parse_gate(["search_regressed > 100"], METRICS).check(values)["failed"]  # no search ran: nothing to pass on


@pytest.mark.parametrize(
    "text, message",
    [
        ("speed_drop > 2", "unknown metric 'speed'"),
        ("regresed > 0", "unknown quantity 'regresed'"),
        ("regressed_low > 0", "regressed has no interval"),
        ("regressed >> 0", "bad operator '>>'"),
        ("regressed >", "expected QUANTITY OP NUMBER"),
        ("regressed > 0 and improved > 0", "join conditions with 'or'"),
        ("regressed > 0 or", "join conditions with 'or'"),
        ("regressed > 0; rm", "unexpected ';'"),
        ("  ", "--fail-if is empty"),
    ],
)
def test_bad_gates_are_refused_in_one_line(text, message):
    with pytest.raises(WorldagentError) as error:
        parse_gate([text], METRICS)
    assert message in str(error.value) and "\n" not in str(error.value)
