"""A PettingZoo ``ParallelEnv`` over the pure-JAX Resource Harvest env.

Agents are ``agent_0`` .. ``agent_3`` (spawn corners TL, TR, BL, BR). Each ``reset`` plays a
new generated map unless a fixed ``world`` is given (at construction or as
``options={"world": map}``); ``reset(seed=s)`` makes the sequence of maps and episodes
reproducible. Inputs are checked here, on the host, so bad ones get a one-line
``WorldagentError``. Re-exported from ``worldagent.envs.adapters``.
"""

from __future__ import annotations

import functools

import gymnasium
import jax
import numpy as np
from pettingzoo import ParallelEnv

from worldagent.envs.harvest.env import NUM_ACTIONS, Harvest, HarvestParams
from worldagent.envs.harvest.maps import MapConfig, generate_maps
from worldagent.envs.harvest.world import HarvestMap, index_maps
from worldagent.errors import WorldagentError


@functools.lru_cache(maxsize=8)
def _compiled(env: Harvest):
    """Jitted ``reset`` and ``step``, shared by every adapter over the same env."""
    return jax.jit(env.reset), jax.jit(env.step)


class HarvestParallelEnv(ParallelEnv):
    """Resource Harvest as a PettingZoo parallel environment.

    Args:
        env: the static configuration (``Harvest()`` by default).
        params: ``HarvestParams`` (``env.default_params`` by default; build with ``make_params``).
        map_config: the generator's settings for the maps sampled at each reset.
        world: a fixed map to play on instead of sampling one.
        render_mode: ``None`` or ``"rgb_array"``.
    """

    metadata = {"name": "worldagent_harvest_v0", "render_modes": ["rgb_array"], "render_fps": 10, "is_parallelizable": True}

    def __init__(
        self,
        env: Harvest | None = None,
        params: HarvestParams | None = None,
        map_config: MapConfig = MapConfig(),
        world: HarvestMap | None = None,
        render_mode: str | None = None,
    ):
        self.env = Harvest() if env is None else env
        self.params = self.env.default_params if params is None else params
        if not isinstance(self.params, HarvestParams):
            raise WorldagentError(f"params must be HarvestParams (see make_params); got {type(self.params).__name__}.")
        if render_mode not in (None, "rgb_array"):
            raise WorldagentError(f"render_mode {render_mode!r} is not supported; use None or 'rgb_array'.")
        map_config.validate()
        if world is not None:
            self.env.check_world(world)
        self.map_config, self.world, self.render_mode = map_config, world, render_mode
        self.possible_agents = [f"agent_{i}" for i in range(self.env.num_agents)]
        self.agents: list[str] = []
        low_high = dict(low=0, high=1, shape=self.env.observation_shape, dtype=np.uint8)
        self._observation_spaces = {agent: gymnasium.spaces.Box(**low_high) for agent in self.possible_agents}
        self._action_spaces = {agent: gymnasium.spaces.Discrete(NUM_ACTIONS) for agent in self.possible_agents}
        self._rng = np.random.default_rng()
        self._reset_fn, self._step_fn = _compiled(self.env)
        self._state = None
        self._key = None

    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        return self._observation_spaces[agent]

    def action_space(self, agent: str) -> gymnasium.spaces.Discrete:
        return self._action_spaces[agent]

    def _next_seed(self) -> int:
        return int(self._rng.integers(0, 2**31))

    def reset(self, seed: int | None = None, options: dict | None = None):
        """Start an episode on a new map (or the fixed / given one); returns ``(obs, infos)``."""
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        world = (options or {}).get("world", self.world)
        map_seed = None
        if world is None:
            map_seed = self._next_seed()
            world = index_maps(generate_maps([map_seed], self.map_config), 0)
        else:
            self.env.check_world(world)
        self._key = jax.random.key(self._next_seed())
        self._key, key_reset = jax.random.split(self._key)
        obs, self._state = self._reset_fn(key_reset, world, self.params)
        self.agents = self.possible_agents[:]
        obs = np.asarray(obs)
        return (
            {agent: obs[i] for i, agent in enumerate(self.agents)},
            {agent: {"map_seed": map_seed} for agent in self.agents},
        )

    def step(self, actions: dict):
        """Advance all agents; returns ``(obs, rewards, terminations, truncations, infos)`` dicts."""
        if not self.agents:
            raise WorldagentError("the episode is over; call reset() before step().")
        unknown = set(actions) - set(self.agents)
        missing = set(self.agents) - set(actions)
        if unknown or missing:
            raise WorldagentError(f"give one action per live agent {self.agents}; unknown {sorted(unknown)}, missing {sorted(missing)}.")
        action = self.env.check_action(np.array([actions[agent] for agent in self.possible_agents]))
        self._key, key_step = jax.random.split(self._key)
        obs, self._state, reward, terminated, truncated, info = self._step_fn(key_step, self._state, action, self.params)
        obs, reward, terminated, truncated = (np.asarray(x) for x in (obs, reward, terminated, truncated))
        info = {name: np.asarray(value) for name, value in info.items()}
        agents = self.agents
        infos = {agent: {name: bool(value[i]) for name, value in info.items()} for i, agent in enumerate(agents)}
        if terminated.any() or truncated.any():
            self.agents = []
        return (
            {agent: obs[i] for i, agent in enumerate(agents)},
            {agent: float(reward[i]) for i, agent in enumerate(agents)},
            {agent: bool(terminated[i]) for i, agent in enumerate(agents)},
            {agent: bool(truncated[i]) for i, agent in enumerate(agents)},
            infos,
        )

    def episode_metrics(self) -> dict:
        """The current episode's metrics (see ``metrics.episode_metrics``) as Python values."""
        if self._state is None:
            raise WorldagentError("no episode yet; call reset() first.")
        return jax.tree_util.tree_map(lambda x: np.asarray(x).tolist(), self.env.metrics(self._state))

    def render(self):
        """An RGB array uint8[H*16, W*16, 3] of the current state (``render_mode="rgb_array"``)."""
        if self.render_mode is None or self._state is None:
            return None
        from worldagent.envs.harvest.render import draw_state

        return np.asarray(draw_state(self._state, self.env, observer=None))

    def close(self):
        pass
