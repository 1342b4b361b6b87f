"""Resource Harvest (paper §5.1.2, §6.2.2; rules after Perolat et al. 2017), pure JAX.

Four agents, one per spawn corner, share a grid of walls and apples. A step is a pipeline of
small pure functions:

    random_draws -> mask_actions -> rotate -> move -> harvest -> fire_beams
                 -> advance_tag_out -> regrow -> (accumulate metrics) -> observe

Beams fire from the positions after this step's moves; an agent hit at step t is off the map
for the next ``tag_out_steps`` step results and returns to its corner (``advance_tag_out``).

Actions (``NUM_ACTIONS = 8``): 0 stand still, 1 forward, 2 backward, 3 left, 4 right (moves
relative to the heading; the heading is kept), 5 rotate left, 6 rotate right, 7 TAG. TAG is a
no-op for agents whose ``params.can_tag`` is False (all by default). Headings: 0 north (up),
1 east, 2 south, 3 west; top agents start facing south, bottom agents north.

Observations: uint8[N, V, V, 4] of 0/1, each agent's egocentric window rotated so that its
heading is up (row 0 is farthest ahead). The agent sits at row ``V - 1 - view_behind``, column
``V // 2``. Channels: walls (the outside of the grid counts as wall), apples, other agents, and
a constant plane that is 1 while the agent is tagged out (its other channels are then 0).
uint8 keeps DQN replay buffers small; networks cast to float.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from worldagent.envs.core import Environment, check_actions
from worldagent.envs.harvest.metrics import episode_metrics
from worldagent.envs.harvest.world import HarvestMap, spawn_corners
from worldagent.errors import WorldagentError

NUM_AGENTS = 4
NOOP, FORWARD, BACKWARD, LEFT, RIGHT, ROTATE_LEFT, ROTATE_RIGHT, TAG = range(8)
NUM_ACTIONS = 8
VIEW_SIZE, VIEW_BEHIND, BEAM_LENGTH = 15, 2, 5  # defaults of ``Harvest``; their sources are in its docstring
ACTION_NAMES = ("noop", "forward", "backward", "left", "right", "rotate_left", "rotate_right", "tag")
NUM_CHANNELS = 4  # walls, apples, other agents, tagged-out flag
WALL_BIT, APPLE_BIT, AGENT_BIT, TAGGED_OUT_BIT = (np.uint8(1 << c) for c in range(NUM_CHANNELS))  # cell codes, bit c = channel c

HEADING_STEP = np.array([[-1, 0], [0, 1], [1, 0], [0, -1]], dtype=np.int32)  # N, E, S, W as (drow, dcol)
INITIAL_HEADING = np.array([2, 2, 0, 0], dtype=np.int32)  # TL, TR face south; BL, BR face north
MOVE_TURN = np.array([0, 0, 2, 3, 1, 0, 0, 0], dtype=np.int32)  # quarter turns from heading to the move
IS_MOVE = np.array([0, 1, 1, 1, 1, 0, 0, 0], dtype=bool)
ROTATION = np.array([0, 0, 0, 0, 0, 3, 1, 0], dtype=np.int32)  # quarter turns clockwise

# Perolat et al. (2017): regrowth probability by the number L of apples within radius 2.
REGROWTH_RADIUS = 2
DISC_OFFSETS = [
    (dr, dc)
    for dr in range(-REGROWTH_RADIUS, REGROWTH_RADIUS + 1)
    for dc in range(-REGROWTH_RADIUS, REGROWTH_RADIUS + 1)
    if 0 < dr * dr + dc * dc <= REGROWTH_RADIUS**2
]
MAX_NEIGHBOURS = len(DISC_OFFSETS)  # 12


def perolat_regrowth_table() -> np.ndarray:
    """f32[13]: probability by L = 0..12: 0 for L=0, 0.01 for 1-2, 0.05 for 3-4, 0.1 above."""
    count = np.arange(MAX_NEIGHBOURS + 1)
    return np.select([count == 0, count <= 2, count <= 4], [0.0, 0.01, 0.05], 0.1).astype(np.float32)


@struct.dataclass
class HarvestParams:
    """Traced parameters.

    Attributes:
        can_tag: bool[4], which agents may TAG (none by default; agent 0 in the paper's
            influencing experiment, §6.2.2).
        regrowth_probability: f32[13], regrowth chance per step by neighbour count L.
        tag_out_steps: steps a tagged agent is removed from the map (25).
        max_steps: episode length; the episode is truncated after it (1000, Perolat).
    """

    can_tag: jax.Array
    regrowth_probability: jax.Array
    tag_out_steps: jax.Array
    max_steps: jax.Array


@struct.dataclass
class HarvestState:
    """Everything that changes during an episode, plus the world and per-episode accumulators.

    Attributes:
        world: the map the episode is played on (apples regrow only on ``world.apples``).
        apples: bool[H, W] apples now.
        position: int32[N, 2] (row, col) of each agent (meaningless while it is tagged out).
        heading: int32[N] 0 north, 1 east, 2 south, 3 west.
        tagged_timer: int32[N] steps left out of play; 0 means on the map.
        time: int32 steps taken.
        returns: f32[N] episode return so far.
        reward_time: f32[N] sum over steps of t·r_t (t = 1, 2, ...), for sustainability.
        conflict_steps: int32 steps that ended with at least one agent tagged out.
        untagged_agent_steps: int32 agent-steps that ended on the map, for peace.
        times_tagged: int32[N] how often each agent was hit.
        fired: bool[N] the agents whose TAG beam fired in the last step (none after reset); with
            ``position`` and ``heading`` it says where the beam went (``beam_reach``).
    """

    world: HarvestMap
    apples: jax.Array
    position: jax.Array
    heading: jax.Array
    tagged_timer: jax.Array
    time: jax.Array
    returns: jax.Array
    reward_time: jax.Array
    conflict_steps: jax.Array
    untagged_agent_steps: jax.Array
    times_tagged: jax.Array
    fired: jax.Array


def make_params(can_tag=None, regrowth_probability=None, tag_out_steps: int = 25, max_steps: int = 1000) -> HarvestParams:
    """Host-side builder of ``HarvestParams`` that checks every value (``WorldagentError``)."""
    can_tag = np.zeros(NUM_AGENTS, bool) if can_tag is None else np.asarray(can_tag)
    if can_tag.shape != (NUM_AGENTS,) or not np.isin(can_tag, (0, 1)).all():
        raise WorldagentError(f"can_tag must be 4 booleans, one per agent; got {can_tag.tolist()}.")
    table = perolat_regrowth_table() if regrowth_probability is None else np.asarray(regrowth_probability, np.float32)
    if table.shape != (MAX_NEIGHBOURS + 1,) or not np.all((table >= 0) & (table <= 1)):
        raise WorldagentError(f"regrowth_probability must be 13 probabilities (L = 0..12); got shape {table.shape}.")
    if tag_out_steps < 1 or max_steps < 1:
        raise WorldagentError(f"tag_out_steps ({tag_out_steps}) and max_steps ({max_steps}) must be positive.")
    return HarvestParams(
        can_tag=jnp.asarray(can_tag, bool),
        regrowth_probability=jnp.asarray(table),
        tag_out_steps=jnp.int32(tag_out_steps),
        max_steps=jnp.int32(max_steps),
    )


def mask_actions(action: jax.Array, on_map: jax.Array, can_tag: jax.Array) -> jax.Array:
    """int32[N]: agents off the map do nothing, and TAG is a no-op without permission."""
    allowed = on_map & ((action != TAG) | can_tag)
    return jnp.where(allowed, action, NOOP).astype(jnp.int32)


def rotate(heading: jax.Array, action: jax.Array) -> jax.Array:
    """int32[N]: headings after the rotate actions."""
    return (heading + jnp.asarray(ROTATION)[action]) % 4


def move(priority: jax.Array, position: jax.Array, heading: jax.Array, action: jax.Array, on_map: jax.Array, walls: jax.Array) -> jax.Array:
    """int32[N, 2]: positions after the move actions.

    A move fails into a wall, off the grid, or into a cell another agent stands on at the start
    of the step (agents block, even if about to leave). Agents claiming the same free cell are
    ranked by ``priority`` (int32[N], a uniformly random permutation drawn from the step's key);
    the highest takes it, the rest stay. So each claimant wins with equal chance, and the
    outcome is a function of the key.
    """
    num_agents = position.shape[0]
    height, width = walls.shape
    wants = on_map & jnp.asarray(IS_MOVE)[action]
    step = jnp.asarray(HEADING_STEP)[(heading + jnp.asarray(MOVE_TURN)[action]) % 4]
    target = position + step
    inside = (target[:, 0] >= 0) & (target[:, 0] < height) & (target[:, 1] >= 0) & (target[:, 1] < width)
    free = inside & ~walls.at[target[:, 0], target[:, 1]].get(mode="fill", fill_value=True)
    same_cell = (target[:, None, :] == position[None, :, :]).all(-1)  # [i, j]: i targets j's cell
    blocked = (same_cell & on_map[None, :] & ~jnp.eye(num_agents, dtype=bool)).any(axis=1)
    claims = wants & free & ~blocked
    same_target = (target[:, None, :] == target[None, :, :]).all(-1)
    beaten = (same_target & claims[None, :] & (priority[None, :] > priority[:, None])).any(axis=1)
    return jnp.where((claims & ~beaten)[:, None], target, position)


def harvest(apples: jax.Array, position: jax.Array, on_map: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(apples bool[H, W], harvested bool[N])``: agents on an apple take it (+1 each)."""
    harvested = on_map & apples[position[:, 0], position[:, 1]]
    rows = jnp.where(harvested, position[:, 0], apples.shape[0])  # out-of-range rows are dropped
    return apples.at[rows, position[:, 1]].set(False, mode="drop"), harvested


def beam_cells(position: jax.Array, heading: jax.Array, length: int) -> jax.Array:
    """int32[N, 3, L, 2]: the cells of each agent's beam, by lane (left, centre, right) and distance 1..L."""
    forward = jnp.asarray(HEADING_STEP)[heading]  # [N, 2]
    right = jnp.asarray(HEADING_STEP)[(heading + 1) % 4]
    lane = jnp.arange(-1, 2)[None, :, None, None] * right[:, None, None, :]
    distance = jnp.arange(1, length + 1)[None, None, :, None] * forward[:, None, None, :]
    return position[:, None, None, :] + lane + distance


def beam_reach(position: jax.Array, heading: jax.Array, firing: jax.Array, walls: jax.Array, length: int) -> tuple[jax.Array, jax.Array]:
    """``(cells int32[N, 3, L, 2], lit bool[N, 3, L])``: each agent's beam cells and which of them
    its beam reaches when it fires (each lane stops at its first wall or the grid edge)."""
    cells = beam_cells(position, heading, length)
    is_wall = walls.at[cells[..., 0], cells[..., 1]].get(mode="fill", fill_value=True)
    return cells, jnp.cumprod(~is_wall, axis=-1).astype(bool) & firing[:, None, None]


def fire_beams(position: jax.Array, heading: jax.Array, firing: jax.Array, on_map: jax.Array, walls: jax.Array, length: int) -> jax.Array:
    """bool[N]: agents hit by another agent's beam.

    The beam is 3 cells wide and ``length`` long; each lane stops at its first wall (or the
    grid edge). It passes through agents, hitting every one on it.
    """
    cells, lit = beam_reach(position, heading, firing, walls, length)  # [N, 3, L, 2], [N, 3, L]
    on_beam = (cells[:, :, :, None, :] == position[None, None, None, :, :]).all(-1) & lit[..., None]  # [shooter, 3, L, target]
    hit = on_beam.any(axis=(1, 2)) & ~jnp.eye(position.shape[0], dtype=bool)
    return hit.any(axis=0) & on_map


def advance_tag_out(timer, hit, was_on_map, position, heading, corners, tag_out_steps):
    """``(timer, position, heading)`` after a step of tag-outs.

    An agent hit in step t is off the map at the end of steps t .. t+tag_out_steps-1 and back at
    its corner, facing its initial heading, at the end of step t+tag_out_steps; if another agent
    stands on the corner it waits a step.
    """
    was_out = ~was_on_map
    timer = jnp.where(was_out, timer - 1, timer)
    due = was_out & (timer == 0)
    stays_on_map = was_on_map & ~hit
    corner_taken = ((corners[:, None, :] == position[None, :, :]).all(-1) & stays_on_map[None, :]).any(axis=1)
    returns = due & ~corner_taken
    timer = jnp.where(due & corner_taken, 1, timer)
    timer = jnp.where(hit, tag_out_steps, timer)
    position = jnp.where(returns[:, None], corners, position)
    heading = jnp.where(returns, jnp.asarray(INITIAL_HEADING), heading)
    return timer, position, heading


def shift_sum(grid: jax.Array, offsets) -> jax.Array:
    """uint8[H, W]: for each cell, how many of ``grid``'s cells at ``offsets`` are set (zero outside; at most 255 offsets)."""
    height, width = grid.shape
    pad = max(max(abs(dr), abs(dc)) for dr, dc in offsets)
    padded = jnp.pad(grid.astype(jnp.uint8), pad)  # uint8: counts stay small and SIMD lanes are 4x wider
    return sum(padded[pad + dr : pad + dr + height, pad + dc : pad + dc + width] for dr, dc in offsets)


def regrow(draw: jax.Array, apples: jax.Array, apple_sites: jax.Array, occupied: jax.Array, table: jax.Array) -> jax.Array:
    """bool[H, W]: apples after regrowth.

    An empty apple site with no agent on it regrows with probability ``table[L]``, L the number
    of apples within Euclidean distance 2 (Perolat et al. 2017): where ``draw`` (f32[H, W],
    uniform in [0, 1)) is below ``table[L]``.
    """
    count = shift_sum(apples, DISC_OFFSETS)
    chance = table[count]
    grows = apple_sites & ~apples & ~occupied & (draw < chance)
    return apples | grows


def mix32(x: jax.Array) -> jax.Array:
    """uint32 avalanche mixer (MurmurHash3's finaliser): a bijection that scrambles every bit."""
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x85EBCA6B)
    x = x ^ (x >> 13)
    x = x * jnp.uint32(0xC2B2AE35)
    return x ^ (x >> 16)


def random_draws(key: jax.Array, shape: tuple[int, int]) -> tuple[jax.Array, jax.Array]:
    """``(priority int32[N], draw f32[H, W])``: a random ranking of the agents and a uniform per cell.

    One threefry call yields a 64-bit seed; each cell's 32 random bits are a hash of (seed,
    cell index). Threefry for every cell would cost about 60% of a step on CPU; the hash
    costs a few integer operations and passes the regrowth frequency tests.
    """
    seed = jax.random.bits(key, (2,), jnp.uint32)
    index = jnp.arange(NUM_AGENTS + shape[0] * shape[1], dtype=jnp.uint32)
    bits = mix32(mix32(index * jnp.uint32(0x9E3779B9) ^ seed[0]) + seed[1])
    priority = jnp.argsort(jnp.argsort(bits[:NUM_AGENTS])).astype(jnp.int32)  # a uniform random permutation
    uniform = (bits[NUM_AGENTS:] >> 8).astype(jnp.float32) * (1.0 / (1 << 24))
    return priority, uniform.reshape(shape)


def occupancy(position: jax.Array, on_map: jax.Array, shape: tuple[int, int]) -> jax.Array:
    """bool[H, W]: cells with an agent on them."""
    rows = jnp.where(on_map, position[:, 0], shape[0])
    return jnp.zeros(shape, bool).at[rows, position[:, 1]].set(True, mode="drop")


@dataclasses.dataclass(frozen=True)
class Harvest(Environment):
    """The Resource Harvest environment (static configuration).

    Attributes:
        num_agents: must be 4, one per spawn corner.
        view_size: side V of the square egocentric window (odd).
        view_behind: rows of the window behind the agent; the rest are ahead (the paper: an
            agent "observes the area it is facing").
        beam_length: reach of the TAG beam, cells.
    """

    num_agents: int = NUM_AGENTS
    view_size: int = VIEW_SIZE
    view_behind: int = VIEW_BEHIND
    beam_length: int = BEAM_LENGTH

    # every episode runs max_steps, so small calls lose little: at 64 an episode costs 15% more than at 256, but a
    # CMA-ES generation (168 episodes, padded to 192) 14% less and a BO round or a confirmation (32, 64) 3.5x less
    # (benchmarks/results/episodes-per-call-cpu.json)
    cpu_episodes_per_call: ClassVar[int] = 64

    def __post_init__(self):
        if self.num_agents != NUM_AGENTS:
            raise WorldagentError(f"Resource Harvest has exactly 4 agents (one per spawn corner); got num_agents={self.num_agents}.")
        if self.view_size < 1 or self.view_size % 2 == 0 or not 0 <= self.view_behind < self.view_size:
            raise WorldagentError(f"view_size must be odd and view_behind in [0, view_size); got {self.view_size}, {self.view_behind}.")
        if self.beam_length < 1:
            raise WorldagentError(f"beam_length must be positive; got {self.beam_length}.")

    @property
    def default_params(self) -> HarvestParams:
        return make_params()

    @property
    def num_actions(self) -> int:
        return NUM_ACTIONS

    @property
    def observation_shape(self) -> tuple[int, ...]:
        return (self.view_size, self.view_size, NUM_CHANNELS)

    # Host-side checks for API boundaries (adapters, CLI); the pure functions below trust input.
    def check_world(self, world: HarvestMap) -> None:
        """Raise ``WorldagentError`` if ``world`` is not a playable (unbatched) map."""
        if not isinstance(world, HarvestMap):
            raise WorldagentError(f"expected a HarvestMap, got {type(world).__name__}; build one with HarvestMap.from_str or generate_maps.")
        world.validate()
        if np.ndim(world.walls) != 2:
            raise WorldagentError(f"expected one map of shape (H, W); got {np.shape(world.walls)} (vmap over a batch instead).")

    def check_action(self, action: Any) -> np.ndarray:
        """int[4] actions in [0, 8), else ``WorldagentError``."""
        return check_actions(action, NUM_ACTIONS, (self.num_agents,))

    def reset(self, key: jax.Array, world: HarvestMap, params: HarvestParams) -> tuple[jax.Array, HarvestState]:
        """Agents at their corners, the world's apples in place (deterministic; ``key`` unused).

        Returns:
            ``(obs uint8[4, V, V, 4], state)``.
        """
        del key
        world = HarvestMap(walls=jnp.asarray(world.walls, bool), apples=jnp.asarray(world.apples, bool))
        height, width = world.walls.shape
        state = HarvestState(
            world=world,
            apples=jnp.asarray(world.apples, bool),
            position=jnp.asarray(spawn_corners(height, width)),
            heading=jnp.asarray(INITIAL_HEADING),
            tagged_timer=jnp.zeros(NUM_AGENTS, jnp.int32),
            time=jnp.int32(0),
            returns=jnp.zeros(NUM_AGENTS, jnp.float32),
            reward_time=jnp.zeros(NUM_AGENTS, jnp.float32),
            conflict_steps=jnp.int32(0),
            untagged_agent_steps=jnp.int32(0),
            times_tagged=jnp.zeros(NUM_AGENTS, jnp.int32),
            fired=jnp.zeros(NUM_AGENTS, bool),
        )
        return self.observe(state, params), state

    def step(self, key: jax.Array, state: HarvestState, action: jax.Array, params: HarvestParams):
        """One simultaneous step of all four agents.

        Args:
            action: int[4], one action per agent.

        Returns:
            ``(obs uint8[4, V, V, 4], state, reward f32[4], terminated bool[4], truncated bool[4],
            info)``; ``info`` holds bool[4] ``harvested``, ``hit`` and ``tagged_out``.
        """
        walls = state.world.walls
        priority, draw = random_draws(key, walls.shape)
        on_map = state.tagged_timer == 0
        action = mask_actions(action, on_map, params.can_tag)
        heading = rotate(state.heading, action)
        position = move(priority, state.position, heading, action, on_map, walls)
        apples, harvested = harvest(state.apples, position, on_map)
        fired = action == TAG  # masked: only agents on the map and allowed to tag
        hit = fire_beams(position, heading, fired, on_map, walls, self.beam_length)
        corners = jnp.asarray(spawn_corners(*walls.shape))
        timer, position, heading = advance_tag_out(state.tagged_timer, hit, on_map, position, heading, corners, params.tag_out_steps)
        now_on_map = timer == 0
        apples = regrow(draw, apples, state.world.apples, occupancy(position, now_on_map, walls.shape), params.regrowth_probability)

        reward = harvested.astype(jnp.float32)
        time = state.time + 1
        state = state.replace(
            apples=apples,
            position=position,
            heading=heading,
            tagged_timer=timer,
            time=time,
            returns=state.returns + reward,
            reward_time=state.reward_time + reward * time.astype(jnp.float32),
            conflict_steps=state.conflict_steps + (~now_on_map).any().astype(jnp.int32),
            untagged_agent_steps=state.untagged_agent_steps + now_on_map.sum(dtype=jnp.int32),
            times_tagged=state.times_tagged + hit.astype(jnp.int32),
            fired=fired,
        )
        terminated = jnp.zeros(NUM_AGENTS, bool)
        truncated = jnp.broadcast_to(time >= params.max_steps, (NUM_AGENTS,))
        info = {"harvested": harvested, "hit": hit, "tagged_out": ~now_on_map}
        return self.observe(state, params), state, reward, terminated, truncated, info

    def observe(self, state: HarvestState, params: HarvestParams) -> jax.Array:
        """uint8[4, V, V, 4]: every agent's rotated egocentric window (see the module docstring)."""
        del params
        # Materialise the state first: otherwise XLA fuses the step (or autoreset's select) that
        # produced it into every window cell and recomputes it there, about 2x slower.
        state = jax.lax.optimization_barrier(state)
        size, behind = self.view_size, self.view_behind
        ahead, half = size - 1 - behind, size // 2
        on_map = state.tagged_timer == 0
        agents = occupancy(state.position, on_map, state.apples.shape)
        codes = state.world.walls.astype(jnp.uint8) * WALL_BIT | state.apples.astype(jnp.uint8) * APPLE_BIT | agents.astype(jnp.uint8) * AGENT_BIT
        pad = max(ahead, behind, half)  # beyond the edge is wall
        height, width = codes.shape
        side = max(height, width)  # square, so that the board and its transpose stack
        padded = jnp.pad(codes, ((pad, pad + side - height), (pad, pad + side - width)), constant_values=WALL_BIT)
        # A window rotated by quarter turns is a slice of the board or of its transpose, flipped:
        # cheaper than rotating every window four ways and selecting one.
        boards = jnp.stack([padded, padded.T])
        corner_offset = jnp.array([[-ahead, -half], [-half, -behind], [-behind, -half], [-half, -ahead]], jnp.int32)

        def window(position, heading):
            origin = position + corner_offset[heading] + pad  # world-frame top-left, for N, E, S, W
            sideways = heading % 2 == 1  # E and W read the transposed board
            origin = jnp.where(sideways, origin[::-1], origin)
            patch = jax.lax.dynamic_slice(boards, (sideways.astype(jnp.int32), origin[0], origin[1]), (1, size, size))[0]
            patch = jnp.where((heading == 1) | (heading == 2), patch[::-1], patch)  # E, S: flip rows
            return jnp.where((heading == 2) | (heading == 3), patch[:, ::-1], patch)  # S, W: flip columns

        patches = jax.vmap(window)(state.position, state.heading)  # uint8[N, V, V] codes
        self_bit = np.zeros((size, size), np.uint8)
        self_bit[ahead, half] = AGENT_BIT  # the observer is not an "other agent"
        codes = jnp.where(on_map[:, None, None], patches & ~self_bit, TAGGED_OUT_BIT)
        # One fused elementwise op unpacks the bits into the four 0/1 channels.
        return (codes[..., None] >> jnp.arange(NUM_CHANNELS, dtype=jnp.uint8)) & jnp.uint8(1)

    def metrics(self, state: HarvestState) -> dict[str, jax.Array]:
        """Per-episode metrics of the episode so far (see ``metrics.episode_metrics``)."""
        return episode_metrics(state.returns, state.reward_time, state.conflict_steps, state.untagged_agent_steps, state.time)
