"""The world's share of an episode's outcome, as the report says it (DESIGN.md "Noise: the world's share and confirmation").

The numbers are ``results.world_share_summary``'s (``analysis.noise`` over the stored random campaign: no new
episode is played); this module only words them: a paragraph for the random-evaluation section and one line per
env for "where this run departs from the paper". docs/noise.md says how to read them.
"""

from __future__ import annotations

import numpy as np

from worldagent.analysis.noise import repeats_for
from worldagent.reports.page import esc, fmt

LUCK_SHARE = 0.25  # below this share of an episode's variance, a search over worlds mostly finds luck
RELIABLE = 0.8  # the reliability a world's score needs before its ranking says much


def finite(value) -> bool:
    return value is not None and np.isfinite(value)


def interval(share: dict | None) -> str:
    """ "0.097 [0.065, 0.136]" of a ``WorldShare.as_dict()``; "n/a" without one."""
    if not share or not finite(share.get("icc")):
        return "n/a"
    return f"{fmt(share['icc'], 2)} [{fmt(share['low'], 2)}, {fmt(share['high'], 2)}]"


def verdict(summary: dict, metric: str) -> str:
    """What the share of ``metric`` means for a search over worlds: mostly luck, or mostly the world."""
    share = summary.get("metrics", {}).get(metric) or {}
    icc = share.get("icc")
    if not finite(icc):
        return ""
    more = repeats_for(icc, RELIABLE)
    fix = f"{more} episodes per world give a score of reliability {RELIABLE}" if more and more > summary["repeats"] else ""
    if icc < LUCK_SHARE:
        return (
            f"below {LUCK_SHARE}, a search over worlds mostly finds luck: the worst-scoring worlds are mostly the worst dice. "
            "The fix is more episodes per world, not more worlds" + (f": {fix}." if fix else ".")
        )
    return "the world carries a real part of the outcome: a search over worlds finds worlds, not only dice" + (f"; {fix}." if fix else ".")


def share_paragraph(summary: dict, metric: str) -> str:
    """The random-evaluation section's paragraph: the world's share of ``metric`` and of the failure event with their
    intervals, the reliability of a world's score at the run's repeats, failing episodes on failing worlds, and what
    that means; "" when the campaign has fewer than 2 episodes per world."""
    if not summary:
        return ""
    share = summary.get("metrics", {}).get(metric)
    parts = [
        f"<strong>The world's share</strong> of an episode's {esc(metric)} (one-way random-effects ICC(1) over "
        f"{fmt(summary['worlds'])} worlds × {summary['repeats']} episodes, 95% interval): "
        f"<span data-share='{esc(metric)}'>{interval(share)}</span>"
    ]
    failure = summary.get("failure")
    if failure:
        parts.append(f"; of the failure event ({esc(failure['event'])}): <span data-share='failure'>{interval(failure['share'])}</span>")
    parts.append(". ")
    if share and finite(share.get("reliability")):
        parts.append(
            f"A world's {summary['repeats']}-episode score has reliability {fmt(share['reliability'], 2)} "
            f"[{fmt(share['reliability_low'], 2)}, {fmt(share['reliability_high'], 2)}]: two independent scores of the same worlds "
            "correlate that much (Spearman–Brown). "
        )
    if failure and finite(failure.get("on_failing_worlds")):
        parts.append(
            f"Of the failing episodes ({fmt(100 * failure['episodes_failing'], 2)}% of all), "
            f"<span data-share='on-failing-worlds'>{fmt(100 * failure['on_failing_worlds'], 2)}%</span> fall on worlds that fail "
            "in at least half of theirs. "
        )
    said = verdict(summary, metric)
    if said:
        parts.append(said[0].upper() + said[1:] + " ")
    return "<p class='share'>" + "".join(parts).strip() + " See docs/noise.md.</p>"


def share_note(env: str, summary: dict, metric: str) -> str:
    """One line for "where this run departs from the paper": the env's world share and what it means; "" without one."""
    if not summary:
        return ""
    share = summary.get("metrics", {}).get(metric)
    failure = summary.get("failure")
    text = f"{env}: the world's share of {metric} {interval(share)}"
    if failure:
        text += f", of the failure ({failure['event']}) {interval(failure['share'])}"
    if share and finite(share.get("reliability")):
        text += f"; reliability of a world's score over {summary['repeats']} episodes {fmt(share['reliability'], 2)}"
    icc = (share or {}).get("icc")
    if finite(icc):
        text += (
            " — the paper's searches read a world's score as the world's; here it is mostly luck (more episodes per world, not more worlds)"
            if icc < LUCK_SHARE
            else " — a world's score is mostly the world's, as the paper's searches assume"
        )
    return text + "."
