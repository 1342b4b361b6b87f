"""A scripted reference driver that follows the centreline (a baseline and a drivability test).

It is a privileged policy: it reads the track and its own segment from the env state, aims at a
point ``lookahead`` segments ahead (pure pursuit), and caps its speed by how sharply the road
turns over the next ``brake_horizon`` segments. With only four force directions and no "coast"
action, it picks the force that best closes the gap between its velocity and the one it wants.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from worldagent.envs.racing.env import ACTION_DIRECTIONS, RacingParams, RacingState


@struct.dataclass
class DriverParams:
    """Tuning of the reference driver.

    Attributes:
        lookahead: segments ahead of the agent's segment to aim at.
        brake_horizon: segments ahead over which the road's turning sets the speed.
        turn_slowdown: fraction of top speed lost per radian of upcoming turning.
        min_speed: slowest target speed, as a fraction of top speed.
        max_speed: fastest target speed, as a fraction of top speed.
    """

    lookahead: int = 4
    brake_horizon: int = struct.field(pytree_node=False, default=16)  # an array length: static
    turn_slowdown: float = 0.1
    min_speed: float = 0.2
    max_speed: float = 0.5


def _turning_ahead(centreline: jax.Array, segment: jax.Array, horizon: int) -> jax.Array:
    """Total absolute heading change (rad) of the centreline over ``horizon`` segments ahead."""
    num_points = centreline.shape[0]
    idx = (segment + jnp.arange(horizon + 1)) % num_points
    edges = centreline[(idx + 1) % num_points] - centreline[idx]
    headings = jnp.arctan2(edges[:, 1], edges[:, 0])
    turns = (jnp.diff(headings) + jnp.pi) % (2 * jnp.pi) - jnp.pi
    return jnp.sum(jnp.abs(turns))


def driver_action(state: RacingState, params: RacingParams, driver: DriverParams = DriverParams()) -> jax.Array:
    """i32 action that steers the particle along the centreline (see module docstring)."""
    centreline = state.world.centreline
    num_points = centreline.shape[0]
    target = centreline[(state.segment + driver.lookahead) % num_points]
    to_target = target - state.position
    heading = to_target / jnp.maximum(jnp.linalg.norm(to_target), 1e-6)
    turning = _turning_ahead(centreline, state.segment, driver.brake_horizon)
    top_speed = params.force / params.friction
    speed = top_speed * jnp.clip(driver.max_speed - driver.turn_slowdown * turning, driver.min_speed, driver.max_speed)
    coasting = (1.0 - params.friction) * state.velocity
    gap = speed * heading - coasting
    return jnp.argmax(jnp.asarray(ACTION_DIRECTIONS) @ gap).astype(jnp.int32)
