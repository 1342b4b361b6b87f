"""``accel``: PLR plus edits (Parker-Holder et al. 2022), the edits small Gaussian steps in the latent space.

Worlds not replayed are, half the time, a buffer latent moved by ``mutation_scale`` per
dimension; an edited world enters the buffer when its episode scores high.
"""

from __future__ import annotations

from worldagent.curricula.replay import build_replay

HELP = "ACCEL: PLR plus Gaussian edits of the buffer's latents, kept when they score high"
LATENTS = True  # draws latents of a generator
DEFAULTS = {"edit_prob": 0.5}


def build(worlds, settings: dict, target=None):
    return build_replay("accel", worlds, {**DEFAULTS, **settings}, target)
