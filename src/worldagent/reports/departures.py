"""Where a run departs from the paper: the headline numbers that disagree, each with its likely cause.

The report opens with this box (``departures_section``), so a reader sees first which of the paper's
numbers this run did not reproduce, and why it probably did not: budgets below the paper's (read from the
run's own phase configs against the env's ``paper`` preset), a normalisation the paper does not spell
out, or too few seeds to read a direction from. Each gap links to the section that holds its numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from worldagent.envs import registry
from worldagent.reports.noise import share_note
from worldagent.reports.page import esc, fmt
from worldagent.reports.results import Headline

PAPER_REPEATS = 8  # episodes per world in every evaluation of the paper (§6)
RELATIVE_GAP = 0.25  # ours differs when it is off by more than a quarter of the paper's value ...
ABSOLUTE_GAP = 0.05  # ... and by more than this (rates and normalised rewards live in [0, 1])
# (phase, its config field, the env's paper-preset budget, what it counts): the budgets a gap may come from.
BUDGETS = {
    "random": (("agent", "episodes", "episodes", "training episodes"), ("random", "worlds", "random_worlds", "random worlds")),
    "strategic": (("agent", "episodes", "episodes", "training episodes"), ("strategic", "budget", "strategic_budget", "worlds searched")),
    "influence": (
        ("influence", "seeds", "influence_seeds", "seeds per arm"),
        ("influence", "episodes", "influence_episodes", "training episodes per agent"),
        ("influence", "eval_worlds", "influence_eval_worlds", "evaluation worlds"),
    ),
}
SECTION = {"random": "random", "min": "strategic", "max": "strategic", "influence": "influence"}


@dataclass(frozen=True)
class Departure:
    """One headline number that disagrees with the paper's, why it probably does, and where to read more."""

    row: Headline
    cause: str
    anchor: str


def differs(ours: float | None, paper: float | None) -> bool:
    """Ours and the paper's disagree: they have opposite signs, or lie apart by more than a quarter of the paper's value (and 0.05)."""
    if ours is None or paper is None or not (np.isfinite(ours) and np.isfinite(paper)):
        return False
    if ours * paper < 0:
        return True
    return abs(ours - paper) > max(ABSOLUTE_GAP, RELATIVE_GAP * abs(paper))


def family(key: str) -> str:
    """``harvest.influence.conflict_default`` -> ``influence`` (``min``/``max`` -> ``strategic``)."""
    part = key.split(".")[1]
    return "strategic" if part in ("min", "max") else part


def seeds_of(res: dict) -> int | None:
    """How many seeds trained each influence arm (None: no influence phase)."""
    config = (res.get("influence") or {}).get("config") or res["phases"].get("influence", {}).get("config") or {}
    return len(config["seeds"]) if "seeds" in config else None


def smaller_budgets(res: dict, env: str, kind: str) -> list[str]:
    """ "64 training episodes (the paper's: 10,000)", for each budget of ``kind`` below the paper's preset (one seed is said apart)."""
    paper = registry.get(env).presets.get("paper", {})
    found = []
    for phase, field, budget, words in BUDGETS.get(kind, ()):
        ours, theirs = res["phases"].get(phase, {}).get("config", {}).get(field), paper.get(budget)
        ours, theirs = (len(v) if isinstance(v, (list, tuple)) else v for v in (ours, theirs))
        if field == "seeds" and ours == 1:
            continue
        if isinstance(ours, int) and isinstance(theirs, int) and ours < theirs:
            found.append(f"{ours:,} {words} (the paper's: {theirs:,})")
    repeats = res["phases"].get(kind, {}).get("config", {}).get("repeats")
    if isinstance(repeats, int) and repeats < PAPER_REPEATS:
        found.append(f"{repeats} episodes per world (the paper's: {PAPER_REPEATS})")
    return found


def likely_cause(row: Headline, results: dict) -> str:
    """Why this run's number probably differs: smaller budgets, the normalisation, one seed."""
    env = row.key.split(".")[0]
    res, spec, kind = results[env], registry.get(env), family(row.key)
    causes = []
    if kind == "influence" and seeds_of(res) == 1:
        causes.append("one seed per arm: a single agent per arm cannot show the direction of a change")
    budgets = smaller_budgets(res, env, kind)
    if budgets:
        causes.append("smaller budgets: " + ", ".join(budgets))
    if "normalised" in row.key or "reward_change" in row.key:
        if spec.metrics.bounds is None:
            causes.append("normalised by this run's best single episode, a rule the paper does not give")
    return "; ".join(causes) or "the same budgets as the paper's preset: a real difference, see the section"


def departures(rows: list[Headline], results: dict) -> list[Departure]:
    """The headline rows where ours and the paper's differ (``differs``), each with ``likely_cause`` and its section."""
    return [
        Departure(row, likely_cause(row, results), SECTION.get(row.key.split(".")[1], "headline")) for row in rows if differs(row.ours, row.paper)
    ]


def one_seed_notes(results: dict) -> list[str]:
    """A line per env whose influence arms trained with one seed: what its changes can and cannot say."""
    notes = []
    for env, res in results.items():
        if seeds_of(res) != 1 or "influence" not in res:
            continue
        summary = res["influence"].get("summary", {})
        changes = ", ".join(
            f"{name.replace('_', ' ')} {fmt(v['default']['mean'], 3)} → {fmt(v['influenced']['mean'], 3)}"
            for name, v in summary.items()
            if name in registry.get(env).metrics.highlighted
        )
        notes.append(
            f"{env}: the influence phase trained one seed per arm ({changes}); one seed cannot show which way influencing moves a metric "
            f"(the paper's preset trains {len(registry.get(env).presets.get('paper', {}).get('influence_seeds', ())) or 'several'})."
        )
    return notes


def share_notes(results: dict) -> dict[str, str]:
    """{env: one line}: the world's share of each env's main metric on its random campaign (``reports.noise.share_note``)."""
    shares = {env: (res.get("random") or {}).get("share") for env, res in results.items()}
    notes = {env: share_note(env, share, registry.get(env).metrics.main) for env, share in shares.items() if share}
    return {env: line for env, line in notes.items() if line}


def departures_section(rows: list[Headline], results: dict, preset: str | None = None) -> str:
    """The report's opening box: each number that departs from the paper, its likely cause and its section; one-seed warnings."""
    found = departures(rows, results)
    budgets = (
        f"<p>This run used the <code>{esc(preset)}</code> preset, whose budgets lie below the paper's (Provenance lists them); "
        "<code>worldagent reproduce --preset paper</code> runs the paper's.</p>"
        if preset and preset != "paper"
        else ""
    )
    compared = [r for r in rows if r.ours is not None and r.paper is not None]
    if not compared:
        head = "<p>No headline number of this run can be set beside the paper's yet (the phases that make them have not run).</p>"
    elif not found:
        head = f"<p>All {len(compared)} numbers the paper reports lie within a quarter of its values (and 0.05).</p>"
    else:
        head = (
            f"<p><strong>{len(found)} of the {len(compared)} numbers the paper reports differ from ours</strong> "
            f"(opposite sign, or apart by more than a quarter of the paper's value and {ABSOLUTE_GAP}):</p>"
        )
    body = "".join(
        f"<tr data-departure='{esc(d.row.key)}'><td>{esc(d.row.label)}</td><td class='num'>{fmt(d.row.ours, 3)}</td>"
        f"<td class='num'>{fmt(d.row.paper)}</td><td>{esc(d.cause)}</td><td><a href='#{d.anchor}'>{esc(d.anchor)}</a></td></tr>"
        for d in found
    )
    table = (
        "<table><thead><tr><th>quantity</th><th>ours</th><th>paper</th><th>likely cause</th><th>section</th></tr></thead>"
        f"<tbody>{body}</tbody></table>"
        if found
        else ""
    )
    notes = "".join(f"<li data-flag='one-seed'>{esc(line)}</li>" for line in one_seed_notes(results))
    shares = "".join(f"<li data-share-env='{esc(env)}'>{esc(line)}</li>" for env, line in share_notes(results).items())
    share_list = (
        "<p>How much of an episode's outcome belongs to the world (the paper does not measure it; "
        "<a href='#random'>random evaluation</a>):</p>"
        f"<ul class='share'>{shares}</ul>"
        if shares
        else ""
    )
    return f"<div class='departures'>{budgets}{head}{table}" + (f"<ul class='warning'>{notes}</ul>" if notes else "") + share_list + "</div>"
