"""Particle Racing (paper §5.1.1, Figure 4): a particle driven by unit forces around a track.

The agent is a point with a velocity. Each step it applies a force of fixed size in one of four
directions (+x, -x, +y, -y); its velocity decays by the track's friction, then moves it. Reward
per step is ``-step_penalty`` plus ``lap_reward`` times the fraction of a lap it advanced along
the centreline (so "proportional to its speed along the track"). Leaving the road (distance to
the centreline above the half-width) is a crash: ``-crash_penalty`` and the episode terminates.
One full lap of net progress terminates it too; ``max_steps`` steps without either truncate it.

Where the agent is on the track is found by searching the ``2·search_radius + 1`` centreline
segments around the one it was on at the previous step, not the whole loop: a step costs O(17)
instead of O(K), and a jump across the grass onto another part of the track is not "on the
road" (no shortcuts). The radius covers the largest distance the particle can move in one step
(``force / friction``) on the shortest tracks with margin; ``tests/envs/racing`` checks it.

Observations (``ParticleRacing.observation``):

- ``"route"`` (the default), f32[W·W + 4 + 2·R]: optionally the ``W×W`` window of the world's
  128×128 road mask around the agent (1 = road, 0 = grass, row 0 to the north, column 0 to the
  west), flattened; then the position (x, y) in normalised coordinates, the velocity divided by
  the top speed ``force / friction``, and the route ahead: the R centreline points ``route``
  segments beyond the agent's, relative to the agent, divided by ``ROUTE_SCALE`` (what a
  navigation display shows). With the paper's 16×16 window alone, or the window and the route
  together, neither PPO nor ACKTR learnt to lap within 10,000 episodes; with the route alone
  both do (see ``agents/training.py``).
- ``"surroundings"`` (the paper's, §5.1.1, Figure 4: the road around the agent, its position and
  velocity, no route), f32[W·W + C·C + 4]: the ``W×W`` road window at full resolution, then a
  coarse view: the ``reach×reach`` pixels around the agent averaged in blocks to ``C×C``
  (fraction of road per block; pixels off the mask read as grass); then position and velocity
  as above. The fine window shows where the road's edges are (it is 2.5 pixels wide); the
  coarse one shows the corners ahead: at top speed (2.6 pixels a step) a 16-pixel window is 3
  steps of sight, shorter than the ~10 steps braking takes.
- ``"rays"`` (the road around the agent, summarised; no route), f32[R + 10]: how far the road
  runs from the agent in ``RAY_DIRECTIONS`` directions (``road_rays``, over ``reach / 2``
  pixels of the mask), the nearest centreline point relative to the agent over the half-width
  and the road's axis ``(cos 2θ, sin 2θ)`` (``road_here``: the road's middle and its line,
  exactly, but not which way it is driven), the heading (the velocity at unit length, shrinking
  to 0 below ``HEADING_MIN_SPEED`` of the top speed), then position and velocity. The heading is
  the paper's "directional speed" at any speed: with the velocity alone, a cautious learner's
  slow driving (a few pushes' worth) hid which way it was going, and it did not learn to lap.
  With ``heading="kept"`` it is the direction of the last motion above that speed instead,
  kept while the agent is (nearly) at rest, and along the start line at reset, as a car keeps
  its orientation when it stops. On trial: it did not stop ACKTR's seeds from parking
  (``docs/racing.md``), so "motion" stays the default.

Without the route neither names which way along the road is forward: the agent has its
position (tracks run counter-clockwise around the middle) and its velocity. That, not seeing
the road, is what limits learning (``docs/racing.md`` has the designs tried and what they reached).

Training-time respawn (``RacingParams.respawn``): a crash costs the crash penalty, puts the
particle back on the centreline (at rest, or moving along the road at ``respawn_speed``) and the
episode goes on (``crashed`` stays true). With
crashes ending episodes, a learner that crashes after ~15 steps spends the 10,000-episode budget
on 150,000 steps; with respawn every episode lasts until the lap or the time limit and teaches
the whole track. Evaluation always uses the paper's rule (a crash ends the episode).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from worldagent.envs.core import Environment, check_actions, check_finite, check_shape
from worldagent.envs.racing.world import HALF_WIDTH, MAX_EXTENT, NUM_POINTS, RASTER_SIZE, ROAD_SIZE, ROAD_WORDS, Track
from worldagent.errors import WorldagentError

# Unit force directions of the four actions: +x (east), -x (west), +y (north), -y (south).
ACTION_DIRECTIONS = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]], dtype=np.float32)
ACTION_NAMES = ("east", "west", "north", "south")

# Route sensor: centreline points this many segments ahead (~0.0125 units each, so 0.01 to 0.33
# units: from the next step to the next sharp corner at full speed), in units of ROUTE_SCALE.
ROUTE_OFFSETS = (1, 3, 5, 8, 11, 15, 20, 26)
ROUTE_SCALE = 0.1

OBSERVATIONS = ("route", "surroundings", "rays")
HEADING_MIN_SPEED = 0.05  # "rays": below this fraction of the top speed the heading shrinks to 0
HEADINGS = ("motion", "kept")  # "rays": the unit velocity, or the last motion's direction kept at rest
RAY_DIRECTIONS = 16  # "rays": directions, evenly spaced from east, counter-clockwise
RAY_SAMPLES_PER_PIXEL = 2  # "rays": samples along each ray per road-mask pixel


@struct.dataclass
class RacingParams:
    """Traced parameters of Particle Racing.

    The defaults were chosen by driving the reference driver over CarRacing tracks (~3.2 units
    long, tightest turns of radius ~0.034): the top speed ``force / friction = 0.04`` per step is
    two road half-widths, a turn of radius r can be held only below ``sqrt(force·r)`` (~0.012
    in the tightest ones), and velocity responds within ``1 / friction = 10`` steps. A careful
    driver laps in ~200 steps, a fast one in ~100, so the paper's 300-step limit rewards speed
    and punishes hesitation, and sharp corners are worth slowing down for.

    Attributes:
        force: speed added per step in the chosen direction (normalised units / step²).
        friction: fraction of the velocity lost per step to the track.
        step_penalty: reward lost every step (paper: 0.2).
        lap_reward: reward for one whole lap of progress along the centreline.
        crash_penalty: reward lost on leaving the road (paper: 300).
        max_steps: steps after which an episode is truncated (paper: 300).
        half_width: road half-width in normalised units (upstream: 40/6 units = 0.02).
        respawn: on a crash, go back to the centreline at rest and carry on instead of ending
            the episode (for training; see the module docstring).
        respawn_speed: speed after a respawn, as a fraction of the top speed, along the road in
            the driving direction (0: at rest). Without a route sensor the agent tells which
            way the road goes from its velocity; at rest it cannot (``docs/racing.md``).
    """

    force: float = 0.004
    friction: float = 0.1
    step_penalty: float = 0.2
    lap_reward: float = 100.0
    crash_penalty: float = 300.0
    max_steps: int = 300
    half_width: float = HALF_WIDTH
    respawn: bool = False
    respawn_speed: float = 0.0


@struct.dataclass
class RacingState:
    """The agent, where it is on the track, and the episode's running metrics.

    Attributes:
        world: the Track being driven.
        position, velocity: f32[2] in normalised units (per step).
        heading: f32[2] unit direction of the last motion above ``HEADING_MIN_SPEED`` (at reset:
            along the start line).
        segment: i32 index of the centreline segment the agent is on (from point i to i+1).
        arc: f32 position along the loop as a lap fraction in [0, 1).
        progress: f32 net laps driven (unwrapped; negative when driving backwards).
        time: i32 steps taken.
        episode_return: f32 sum of rewards.
        crashed: bool, the agent left the road this episode (with respawn it may carry on).
        lap_completed: bool, the episode ended with a whole lap.
        done: bool, whether the episode has ended (later steps are not meaningful).
    """

    world: Track
    position: jax.Array
    velocity: jax.Array
    heading: jax.Array
    segment: jax.Array
    arc: jax.Array
    progress: jax.Array
    time: jax.Array
    episode_return: jax.Array
    crashed: jax.Array
    lap_completed: jax.Array
    done: jax.Array


def _closest_on_segments(position: jax.Array, starts: jax.Array, ends: jax.Array):
    """Distances f32[S] from ``position`` to segments ``starts[S,2] -> ends[S,2]`` and fractions t."""
    direction = ends - starts
    length_sq = jnp.maximum(jnp.sum(direction**2, axis=-1), 1e-12)
    t = jnp.clip(jnp.sum((position - starts) * direction, axis=-1) / length_sq, 0.0, 1.0)
    closest = starts + t[:, None] * direction
    return jnp.sqrt(jnp.sum((position - closest) ** 2, axis=-1)), t


def locate(centreline: jax.Array, position: jax.Array, near: jax.Array, radius: int):
    """Nearest centreline segment to ``position`` among those within ``radius`` of ``near``.

    Returns:
        (segment i32, arc f32 lap fraction in [0, 1), distance f32 to the centreline).
    """
    centreline = jnp.asarray(centreline)
    num_points = centreline.shape[0]
    candidates = (near + jnp.arange(-radius, radius + 1)) % num_points
    distances, t = _closest_on_segments(position, centreline[candidates], centreline[(candidates + 1) % num_points])
    best = jnp.argmin(distances)
    segment = candidates[best]
    arc = ((segment + t[best]) / num_points) % 1.0
    return segment, arc, distances[best]


def wrap_half(x: jax.Array) -> jax.Array:
    """Wrap a lap-fraction difference into [-0.5, 0.5)."""
    return (x + 0.5) % 1.0 - 0.5


@dataclass(frozen=True)
class ParticleRacing(Environment):
    """The Particle Racing environment; static configuration only (see module docstring).

    Attributes:
        observation: "route" (the default), "surroundings" or "rays" (see the module docstring).
        heading: "rays": "motion" (the unit velocity) or "kept" (the last motion's direction, kept at rest).
        window: side W of the square full-resolution road window, in road-mask pixels (1/64
            units each); 0 for none (the default with "route"; "surroundings" needs one).
        route: segments ahead of the agent's whose centreline points are observed with "route".
        reach: side of the region of the coarse view of "surroundings", road-mask pixels.
        coarse: side C of the coarse view's grid (``reach`` must be a multiple of it).
        search_radius: segments searched either side of the last one to locate the agent.
        num_points: centreline points K of the worlds this env accepts.
    """

    observation: str = "route"
    heading: str = "motion"
    window: int = 0
    route: tuple[int, ...] = ROUTE_OFFSETS
    reach: int = 64
    coarse: int = 16
    search_radius: int = 8
    num_points: int = NUM_POINTS

    num_agents = 1

    def __post_init__(self):
        largest = int(ROAD_SIZE * (1.0 - MAX_EXTENT - 2 * HALF_WIDTH))
        if self.observation not in OBSERVATIONS:
            raise WorldagentError(f"observation={self.observation!r}; use one of {', '.join(OBSERVATIONS)}.")
        if self.heading not in HEADINGS:
            raise WorldagentError(f"heading={self.heading!r}; use one of {', '.join(HEADINGS)}.")
        if not 0 <= self.window <= largest:
            raise WorldagentError(f"window={self.window} is out of range; use 0 (none) to {largest} road-mask pixels.")
        if self.observation == "surroundings" and not (self.window >= 1 and self.coarse >= 1 and self.reach % self.coarse == 0):
            raise WorldagentError(
                f"surroundings need window >= 1 and reach a multiple of coarse (window={self.window}, reach={self.reach}, coarse={self.coarse}); e.g. 16, 64, 16."
            )
        if any(not 1 <= offset < self.num_points for offset in self.route):
            raise WorldagentError(f"route={self.route}: offsets must be 1 to {self.num_points - 1} segments ahead.")
        if self.search_radius < 1 or 2 * self.search_radius + 1 > self.num_points:
            raise WorldagentError(f"search_radius={self.search_radius} must be >= 1 and cover fewer than num_points segments.")

    @property
    def default_params(self) -> RacingParams:
        return RacingParams()

    @property
    def num_actions(self) -> int:
        return len(ACTION_DIRECTIONS)

    @property
    def observation_shape(self) -> tuple[int, ...]:
        if self.observation == "surroundings":
            return (self.window * self.window + self.coarse * self.coarse + 4,)
        if self.observation == "rays":
            return (RAY_DIRECTIONS + 10,)
        return (self.window * self.window + 4 + 2 * len(self.route),)

    # -- host-side checks (shapes always; values whenever they are concrete) ------------------

    def check_world(self, world: Track) -> None:
        """Raise ``WorldagentError`` if ``world`` is not one track this env can drive."""
        if not isinstance(world, Track):
            raise WorldagentError(f"world is a {type(world).__name__}; expected a racing Track (see generate_tracks).")
        check_shape("track centreline", world.centreline, (self.num_points, 2))
        check_shape("track raster", world.raster, (RASTER_SIZE, RASTER_SIZE))
        check_shape("track road mask", world.road, (ROAD_SIZE, ROAD_WORDS))
        if _is_concrete(world.centreline):
            world.validate()

    # -- the functional contract ----------------------------------------------------------------

    def reset(self, key: jax.Array, world: Track, params: RacingParams) -> tuple[jax.Array, RacingState]:
        """Start an episode at the start line (centreline point 0), at rest. ``key`` is unused."""
        self.check_world(world)
        world = jax.tree_util.tree_map(jnp.asarray, world)
        state = RacingState(
            world=world,
            position=world.centreline[0].astype(jnp.float32),
            velocity=jnp.zeros(2, jnp.float32),
            heading=_unit(world.centreline[1] - world.centreline[0]),  # facing along the start line
            segment=jnp.int32(0),
            arc=jnp.float32(0.0),
            progress=jnp.float32(0.0),
            time=jnp.int32(0),
            episode_return=jnp.float32(0.0),
            crashed=jnp.bool_(False),
            lap_completed=jnp.bool_(False),
            done=jnp.bool_(False),
        )
        return self.observe(state, params), state

    def place(self, state: RacingState, position, velocity, params: RacingParams) -> tuple[jax.Array, RacingState]:
        """Put the agent at ``position`` with ``velocity`` (for tests, demos and start-state studies)."""
        for name, value in (("position", position), ("velocity", velocity)):
            check_shape(name, value, (2,))
            if _is_concrete(value):
                check_finite(name, value)
        position = jnp.asarray(position, jnp.float32)
        segment = _global_segment(state.world.centreline, position)
        segment, arc, _ = locate(state.world.centreline, position, segment, self.search_radius)
        state = state.replace(position=position, velocity=jnp.asarray(velocity, jnp.float32), segment=segment, arc=arc)
        return self.observe(state, params), state

    def step(self, key: jax.Array, state: RacingState, action: jax.Array, params: RacingParams):
        """Advance one step (paper §5.1.1). ``key`` is unused: the dynamics are deterministic."""
        if _is_concrete(action):
            check_actions(action, self.num_actions)
        velocity = (1.0 - params.friction) * state.velocity + params.force * jnp.asarray(ACTION_DIRECTIONS)[action]
        position = state.position + velocity
        segment, arc, distance = locate(state.world.centreline, position, state.segment, self.search_radius)
        advance = wrap_half(arc - state.arc)
        progress = state.progress + advance
        time = state.time + 1

        crashed = distance > params.half_width
        lap_completed = jnp.logical_and(progress >= 1.0, ~crashed)
        reward = -params.step_penalty + params.lap_reward * advance - params.crash_penalty * crashed
        respawn = jnp.logical_and(params.respawn, crashed)
        restart = params.respawn_speed * params.force / params.friction
        position, velocity, arc, progress = _respawn_where(respawn, state.world.centreline, segment, position, velocity, arc, progress, restart)
        terminated = jnp.logical_or(jnp.logical_and(crashed, ~respawn), lap_completed)
        truncated = jnp.logical_and(time >= params.max_steps, ~terminated)

        state = state.replace(
            position=position,
            velocity=velocity,
            heading=_kept_heading(velocity, state.heading, params),
            segment=segment,
            arc=arc,
            progress=progress,
            time=time,
            episode_return=state.episode_return + reward,
            crashed=jnp.logical_or(state.crashed, crashed),
            lap_completed=lap_completed,
            done=jnp.logical_or(terminated, truncated),
        )
        info = {"crashed": state.crashed, "lap_completed": lap_completed, "progress": progress}  # crashed: this episode, so far
        return self.observe(state, params), state, reward, terminated, truncated, info

    def metrics(self, state: RacingState) -> dict[str, jax.Array]:
        """Per-episode metrics of the episode so far (see ``episode_metrics``)."""
        return episode_metrics(state)

    def observe(self, state: RacingState, params: RacingParams) -> jax.Array:
        """f32[``observation_shape``]: see the module docstring for each ``observation``."""
        top_speed = params.force / params.friction
        motion = [state.position, state.velocity / top_speed]
        if self.observation == "surroundings":
            fine, coarse = surroundings_view(state.world.road, state.position, self.window, self.reach, self.coarse)
            parts = [fine.reshape(-1), coarse.reshape(-1), *motion]
        elif self.observation == "rays":
            centre, axis = road_here(state.world.centreline, state.segment, state.position)
            if self.heading == "kept":
                heading = state.heading
            else:  # unit length once moving
                heading = state.velocity / jnp.maximum(jnp.linalg.norm(state.velocity), HEADING_MIN_SPEED * top_speed)
            parts = [road_rays(state.world.road, state.position, self.reach // 2), centre / params.half_width, axis, heading, *motion]
        else:
            centreline = state.world.centreline
            ahead = centreline[(state.segment + jnp.asarray(self.route, jnp.int32)) % centreline.shape[0]]
            parts = [*motion, ((ahead - state.position) / ROUTE_SCALE).reshape(-1)]
            if self.window:
                parts.insert(0, road_window(state.world.road, state.position, self.window).reshape(-1))
        return jnp.concatenate([p.astype(jnp.float32) for p in parts])


def _unit(vector: jax.Array) -> jax.Array:
    return (vector / jnp.maximum(jnp.linalg.norm(vector), 1e-12)).astype(jnp.float32)


def _kept_heading(velocity: jax.Array, heading: jax.Array, params: RacingParams) -> jax.Array:
    """The unit velocity once moving faster than ``HEADING_MIN_SPEED`` of the top speed, else ``heading`` as it was."""
    moving = jnp.linalg.norm(velocity) > HEADING_MIN_SPEED * params.force / params.friction
    return jnp.where(moving, _unit(velocity), heading)


def _respawn_where(respawn, centreline, segment, position, velocity, arc, progress, speed=0.0):
    """Where ``respawn``: the agent back at its segment's start point with ``speed`` along it, progress adjusted.

    Progress moves back by the same lap fraction as the position, so a respawn never counts as
    progress (the next step measures its advance from the respawn point).
    """
    back_arc = segment.astype(jnp.float32) / centreline.shape[0]
    ahead = centreline[(segment + 1) % centreline.shape[0]] - centreline[segment]
    return (
        jnp.where(respawn, centreline[segment].astype(jnp.float32), position),
        jnp.where(respawn, speed * ahead / jnp.maximum(jnp.linalg.norm(ahead), 1e-9), velocity),
        jnp.where(respawn, back_arc, arc),
        jnp.where(respawn, progress + wrap_half(back_arc - arc), progress),
    )


def road_window(road: jax.Array, position: jax.Array, window: int) -> jax.Array:
    """u32[W, W] 0/1 on-road pixels of the ``W×W`` window centred on ``position`` (W <= 32).

    ``road`` is bit-packed (``world.pack_road``): the window's rows are one contiguous slice of
    whole packed rows; each row's W bits are then shifted out of the one or two words they span.
    ``Track.validate``'s ``MAX_EXTENT`` keeps the window inside the mask.
    """
    start = jnp.round(_to_pixel_jnp(position, ROAD_SIZE)).astype(jnp.int32) - window // 2
    rows = jax.lax.dynamic_slice(road, (start[0], 0), (window, road.shape[-1]))
    word, shift = start[1] // 32, (start[1] % 32).astype(jnp.uint32)
    low = jnp.take(rows, word, axis=1, mode="clip")
    high = jnp.take(rows, word + 1, axis=1, mode="fill", fill_value=0)
    bits = (low >> shift) | jnp.where(shift > 0, high << ((32 - shift) % 32), 0)
    return (bits[:, None] >> jnp.arange(window, dtype=jnp.uint32)) & 1


def road_pixels(road: jax.Array, position: jax.Array, side: int) -> jax.Array:
    """u32[side, side] 0/1 on-road pixels of the square centred on ``position``; off the mask reads 0 (grass).

    Unpacks the ``side`` rows of ``road`` (bit-packed, ``world.pack_road``) whole, then gathers
    the columns, so any ``side`` and any position work (``road_window``'s single read does not).
    """
    start = jnp.round(_to_pixel_jnp(position, ROAD_SIZE)).astype(jnp.int32) - side // 2
    rows = jnp.take(road, start[0] + jnp.arange(side), axis=0, mode="fill", fill_value=0)
    bits = (rows[:, :, None] >> jnp.arange(32, dtype=jnp.uint32)) & 1  # bit k of word j: column 32·j + k
    return jnp.take(bits.reshape(side, -1), start[1] + jnp.arange(side), axis=1, mode="fill", fill_value=0)


def surroundings_view(road: jax.Array, position: jax.Array, window: int, reach: int, coarse: int) -> tuple[jax.Array, jax.Array]:
    """The "surroundings" observation's images: (u32[W, W] road window, f32[C, C] coarse view).

    The window is ``road_window``'s; the coarse view is the fraction of road pixels in each
    ``reach / C``-pixel block of the ``reach×reach`` square around ``position``.
    """
    side = max(reach, window)
    pixels = road_pixels(road, position, side)
    fine_at, region_at = side // 2 - window // 2, side // 2 - reach // 2  # both centred like road_window
    fine = pixels[fine_at : fine_at + window, fine_at : fine_at + window]
    region = pixels[region_at : region_at + reach, region_at : region_at + reach].astype(jnp.float32)
    block = reach // coarse
    return fine, region.reshape(coarse, block, coarse, block).mean(axis=(1, 3))


def road_here(centreline: jax.Array, segment: jax.Array, position: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The road where the agent is, exactly (the road mask's pixels are 0.78 of a half-width wide):
    (f32[2] the nearest point of the centreline relative to ``position``, f32[2] the road's axis
    ``(cos 2θ, sin 2θ)`` of its direction θ; the same for either way along it, so it holds no route)."""
    num_points = centreline.shape[0]
    start, end = centreline[segment], centreline[(segment + 1) % num_points]
    direction = end - start
    t = jnp.clip(jnp.dot(position - start, direction) / jnp.maximum(jnp.dot(direction, direction), 1e-12), 0.0, 1.0)
    theta = jnp.arctan2(direction[1], direction[0])
    return start + t * direction - position, jnp.stack([jnp.cos(2 * theta), jnp.sin(2 * theta)])


def road_rays(road: jax.Array, position: jax.Array, reach: int) -> jax.Array:
    """f32[RAY_DIRECTIONS] in [0, 1]: how far the road goes from ``position`` in each direction, over ``reach`` pixels.

    Each ray is sampled every half pixel of the road mask (``world.pack_road``; off the mask is
    grass); its value is the fraction of ``reach`` before the first grass sample (1: road all the way).
    """
    angles = jnp.arange(RAY_DIRECTIONS) * (2 * jnp.pi / RAY_DIRECTIONS)
    distances = jnp.arange(1, reach * RAY_SAMPLES_PER_PIXEL + 1) / RAY_SAMPLES_PER_PIXEL  # pixels
    # (row, col) offsets: x (east) is +col, y (north) is -row
    rows = _to_pixel_jnp(position, ROAD_SIZE)[0] - jnp.sin(angles)[:, None] * distances
    cols = _to_pixel_jnp(position, ROAD_SIZE)[1] + jnp.cos(angles)[:, None] * distances
    r, c = jnp.round(rows).astype(jnp.int32), jnp.round(cols).astype(jnp.int32)
    inside = (r >= 0) & (r < road.shape[0]) & (c >= 0) & (c < road.shape[0])
    words = road[jnp.clip(r, 0, road.shape[0] - 1), jnp.clip(c, 0, road.shape[0] - 1) // 32]
    on_road = inside & (((words >> (jnp.clip(c, 0, road.shape[0] - 1) % 32).astype(jnp.uint32)) & 1) == 1)
    clear = jnp.cumprod(on_road, axis=1)  # 1 until the first grass sample
    return clear.sum(axis=1) / distances.shape[0]


def episode_metrics(state: RacingState) -> dict[str, jax.Array]:
    """The per-episode metrics later phases optimise: return, crashed, lap, progress, steps."""
    return {
        "return": state.episode_return,
        "crashed": state.crashed,
        "lap_completed": state.lap_completed,
        "progress": jnp.clip(state.progress, 0.0, 1.0),
        "steps": state.time,
    }


def split_observation(obs, window: int) -> tuple:
    """Split observations ``[..., W·W + 4 + 2·R]`` into (window ``[..., W, W]``, position, velocity, route ``[..., R, 2]``)."""
    cells = window * window
    route = obs[..., cells + 4 :]
    return (
        obs[..., :cells].reshape(*obs.shape[:-1], window, window),
        obs[..., cells : cells + 2],
        obs[..., cells + 2 : cells + 4],
        route.reshape(*obs.shape[:-1], route.shape[-1] // 2, 2),
    )


def _to_pixel_jnp(xy: jax.Array, size: int) -> jax.Array:
    """``world.to_pixel`` in jnp: normalised (x, y) -> continuous (row, col)."""
    return jnp.stack([(1.0 - xy[1]) * size / 2.0 - 0.5, (xy[0] + 1.0) * size / 2.0 - 0.5])


def _global_segment(centreline: jax.Array, position: jax.Array) -> jax.Array:
    """Index of the nearest centreline segment over the whole loop (used only when placing)."""
    distances, _ = _closest_on_segments(position, centreline, jnp.roll(centreline, -1, axis=0))
    return jnp.argmin(distances).astype(jnp.int32)


def _is_concrete(value) -> bool:
    """True when ``value`` holds actual numbers (not a tracer inside jit/vmap/scan)."""
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(value))
