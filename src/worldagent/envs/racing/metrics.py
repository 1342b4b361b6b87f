"""Normalised metrics (paper §6: "we normalise all reported metrics to be between 0 and 1").

The paper does not say how it scaled; we define the scaling once per environment here, and
every report keeps the raw value beside the normalised one.

Particle Racing: a min-max scaling of the episode return over the range the rules allow,

    normalised = clip((raw - low) / (high - low), 0, 1)
    low  = -(crash_penalty + step_penalty · max_steps)   = -360 with the default params
    high = lap_reward                                     =  100

``low`` is the worst an episode can score up to backward progress: crashing on the last
allowed step after paying every step penalty (backward driving below it is clipped to 0).
``high`` is the unreachable ceiling of a lap in zero steps. With these bounds a crash at the
start scores (−300.2 + 360) / 460 = 0.13 and a 200-step lap 0.91, which sits with the paper's
racing figures (minimum 0.13, average 0.87, maximum 0.99, §6.1.1–6.1.2).

Resource Harvest has no rule-given range; reports normalise it by the run's best episode
(``registry.Metrics.normalise``).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from worldagent.envs.racing.env import RacingParams


def racing_return_bounds(params: RacingParams = RacingParams()) -> tuple[float, float]:
    """(low, high) of the racing return used for normalising (see module docstring)."""
    low = -(float(params.crash_penalty) + float(params.step_penalty) * float(params.max_steps))
    return low, float(params.lap_reward)


def normalised_return(raw, params: RacingParams = RacingParams()):
    """Racing episode returns scaled to [0, 1] (paper §6); same shape and array kind as ``raw``.

    Args:
        raw: f32[...] raw episode returns.
        params: the racing params the episodes were played with (they set the bounds).
    """
    low, high = racing_return_bounds(params)
    xp = jnp if not isinstance(raw, (np.ndarray, float, int, list, tuple)) else np
    return xp.clip((xp.asarray(raw) - low) / (high - low), 0.0, 1.0)
