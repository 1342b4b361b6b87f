"""``plr``: Prioritized Level Replay over latents (Jiang et al. 2021; robust PLR, 2021b).

Replays the worlds with the highest learning potential (positive value loss; |TD error| for
DQN), or, with ``--target``, those closest to the target. Settings and their defaults:
``replay.Settings``.
"""

from __future__ import annotations

from worldagent.curricula.replay import build_replay

HELP = "Prioritized Level Replay: replay the latents of highest learning potential (or --target margin)"
LATENTS = True  # draws latents of a generator
DEFAULTS = {"edit_prob": 0.0}


def build(worlds, settings: dict, target=None):
    return build_replay("plr", worlds, {**DEFAULTS, **settings}, target)
