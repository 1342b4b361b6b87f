"""``target``: the paper's influencing made online: replay the worlds closest to the user's target.

``--target "crash_rate > 0.5"`` (an event) or ``--target conflict --minimize`` (a metric): the
buffer ranks latents by the mean margin of their episodes (``scores.TargetScore``) over the last
8 (the episodes the paper rolls out per world), so training keeps returning to the worlds with
the property while the agent learns, instead of a one-off retrain on a fixed selection.
"""

from __future__ import annotations

from worldagent.curricula.replay import build_replay
from worldagent.errors import WorldagentError

HELP = "the user's target online: replay the latents whose episodes come closest to --target"
LATENTS = True  # draws latents of a generator
DEFAULTS = {"edit_prob": 0.0, "window": 8}


def build(worlds, settings: dict, target=None):
    if target is None:
        raise WorldagentError("curriculum target needs --target, e.g. --target 'crash_rate > 0.5' or --target conflict --minimize.")
    return build_replay("target", worlds, {**DEFAULTS, **settings}, target)
