"""Standard interfaces over the pure-JAX envs, so users can bring their own agents.

``HarvestParallelEnv`` is a PettingZoo ``ParallelEnv`` of Resource Harvest (agents
``agent_0..agent_3``, a new seeded map at every reset; see ``envs/harvest/pettingzoo_env.py``).

``ParticleRacingGym`` is a ``gymnasium.Env`` (registered as ``worldagent/ParticleRacing-v0`` by
``import worldagent``)
that draws a new track from CarRacing's generator at every reset, seeded by Gymnasium's own
``np_random``; ``reset(options={"world": track})`` drives a given track instead.
"""

from __future__ import annotations

import gymnasium
import jax
import numpy as np
from gymnasium import spaces

from worldagent.envs.core import check_actions
from worldagent.envs.racing.env import ROUTE_SCALE, ParticleRacing, RacingParams
from worldagent.envs.racing.world import Track

ROUTE_REACH = 2.0  # normalised units: a bound on how far ahead a route point can be, with margin


class ParticleRacingGym(gymnasium.Env):
    """Particle Racing as a Gymnasium env: ``Box(W·W + 4 + 2·R)`` observations, ``Discrete(4)`` actions.

    Args:
        render_mode: ``None`` or ``"rgb_array"`` (a 256×256 picture of the track and agent).
        params: the env's ``RacingParams`` (defaults: the paper's rewards and 300-step limit).
        window: side of the observation's road window, 0 for none (see ``ParticleRacing``).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}

    def __init__(self, render_mode: str | None = None, params: RacingParams | None = None, window: int = 0):
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode {render_mode!r} is not supported; use None or 'rgb_array'.")
        self.render_mode = render_mode
        self.env = ParticleRacing(window=window)
        self.params = params or self.env.default_params
        cells, route = window * window, 2 * len(self.env.route)
        reach = ROUTE_REACH / ROUTE_SCALE  # route points are at most ~0.5 units away
        low = np.concatenate([np.zeros(cells), [-1.5, -1.5, -1.0, -1.0], np.full(route, -reach)]).astype(np.float32)
        high = np.concatenate([np.ones(cells), [1.5, 1.5, 1.0, 1.0], np.full(route, reach)]).astype(np.float32)
        self.observation_space = spaces.Box(low=low, high=high, dtype=np.float32)
        self.action_space = spaces.Discrete(self.env.num_actions)
        self._reset = jax.jit(self.env.reset)
        self._step = jax.jit(self.env.step)
        self._state = None
        self._trail: list[np.ndarray] = []

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        from worldagent.envs.racing.tracks import generate_track

        options = options or {}
        track_seed = None
        if "world" in options:
            world = options["world"]
        else:
            track_seed = int(options.get("track_seed", self.np_random.integers(0, 2**31 - 1)))
            world = generate_track(track_seed)
        self.env.check_world(world)
        obs, self._state = self._reset(jax.random.key(0), world, self.params)
        self._trail = [np.asarray(self._state.position)]
        return np.asarray(obs), {"track_seed": track_seed}

    def step(self, action):
        if self._state is None:
            raise RuntimeError("call reset() before step().")
        action = check_actions(action, self.env.num_actions)
        obs, self._state, reward, terminated, truncated, info = self._step(jax.random.key(0), self._state, np.int32(action), self.params)
        self._trail.append(np.asarray(self._state.position))
        info = {name: np.asarray(value).item() for name, value in info.items()}
        return np.asarray(obs), float(reward), bool(terminated), bool(truncated), info

    def render(self):
        if self.render_mode != "rgb_array" or self._state is None:
            return None
        from worldagent.envs.racing.render import track_image

        image = track_image(self._state.world, 256, np.stack(self._trail), self._trail[-1], bool(self._state.crashed))
        return np.asarray(image)

    @property
    def world(self) -> Track | None:
        """The track of the current episode."""
        return None if self._state is None else self._state.world


def __getattr__(name: str):
    """``HarvestParallelEnv`` (PettingZoo) is re-exported here, imported only when asked for."""
    if name == "HarvestParallelEnv":
        from worldagent.envs.harvest.pettingzoo_env import HarvestParallelEnv

        return HarvestParallelEnv
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
