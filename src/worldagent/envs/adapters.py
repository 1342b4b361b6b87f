"""Standard interfaces over the pure-JAX envs, so users can bring their own agents.

``HarvestParallelEnv`` is a PettingZoo ``ParallelEnv`` of Resource Harvest (agents
``agent_0..agent_3``, a new seeded map at every reset; see ``envs/harvest/pettingzoo_env.py``).

``ParticleRacingGym`` is a ``gymnasium.Env`` (registered as ``worldagent/ParticleRacing-v0`` by
``import worldagent``) that drives a track drawn at every reset, by Gymnasium's own
``np_random``, from a pool of CarRacing tracks generated once and cached on disk
(``vector.track_pool``), so a reset takes well under a millisecond instead of generating a
track (~75 ms). ``reset(options={"track_seed": s})`` generates CarRacing's track ``s``;
``reset(options={"world": track})`` drives a given track. ``gymnasium.make_vec`` of the same id
gives the batched ``vector.ParticleRacingVectorEnv``.
"""

from __future__ import annotations

from pathlib import Path

import gymnasium
import jax
import numpy as np
from gymnasium import spaces

from worldagent.envs.core import check_actions
from worldagent.envs.racing.env import ParticleRacing, RacingParams
from worldagent.envs.racing.world import Track
from worldagent.envs.vector import POOL_SEED, POOL_SIZE, check_pool_arguments, load_pool, observation_space, take
from worldagent.worlds.dataset import WorldDataset


class ParticleRacingGym(gymnasium.Env):
    """Particle Racing as a Gymnasium env: ``Box(W·W + 4 + 2·R)`` observations, ``Discrete(4)`` actions.

    Args:
        render_mode: ``None`` or ``"rgb_array"`` (a 256×256 picture of the track and agent).
        params: the env's ``RacingParams`` (defaults: the paper's rewards and 300-step limit).
        window: side of the observation's road window, 0 for none (see ``ParticleRacing``).
        pool_size: tracks in the pool resets draw from (generated at the first reset that needs
            it, then cached on disk; see ``vector.track_pool``).
        pool: a racing ``worldagent dataset`` file (or ``WorldDataset``) to draw tracks from instead.
        pool_seed: the first CarRacing seed of the generated pool.
        cache_dir: where the generated pool is cached (default ``$XDG_CACHE_HOME/worldagent``
            or ``~/.cache/worldagent``).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}

    def __init__(
        self,
        render_mode: str | None = None,
        params: RacingParams | None = None,
        window: int = 0,
        pool_size: int = POOL_SIZE,
        pool: WorldDataset | Path | str | None = None,
        pool_seed: int = POOL_SEED,
        cache_dir: Path | str | None = None,
    ):
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode {render_mode!r} is not supported; use None or 'rgb_array'.")
        check_pool_arguments(pool_size, pool_seed)
        self.render_mode = render_mode
        self.env = ParticleRacing(window=window)
        self.params = params or self.env.default_params
        self.observation_space = observation_space(self.env)
        self.action_space = spaces.Discrete(self.env.num_actions)
        self._reset = jax.jit(self.env.reset)
        self._reset_from_pool = jax.jit(lambda worlds, index, params: self.env.reset(jax.random.key(0), take(worlds, index), params))
        self._step = jax.jit(self.env.step)
        self._pool_request = (pool, pool_size, pool_seed, cache_dir)
        self._pool: tuple[Track, np.ndarray] | None = None  # (worlds on the device, seeds), loaded at the first reset from it
        self._state = None
        self._trail: list[np.ndarray] = []

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode on a pool track (or ``options["world"]``, or CarRacing's ``options["track_seed"]``).

        Returns:
            (obs f32[D], info ``{"track_seed": CarRacing seed of the track, None for a given world}``).
        """
        super().reset(seed=seed)
        options = options or {}
        if "world" in options:
            world, track_seed = options["world"], None
        elif "track_seed" in options:
            from worldagent.envs.racing.tracks import generate_track

            track_seed = int(options["track_seed"])
            world = generate_track(track_seed)
        else:
            worlds, seeds = self._track_pool()
            index = int(self.np_random.integers(len(seeds)))
            obs, self._state = self._reset_from_pool(worlds, np.int32(index), self.params)
            return self._started(obs, int(seeds[index]))
        self.env.check_world(world)
        obs, self._state = self._reset(jax.random.key(0), world, self.params)
        return self._started(obs, track_seed)

    def _started(self, obs, track_seed: int | None):
        """The observation and info of a reset, with the trail started at the start line."""
        self._trail = [np.asarray(self._state.position)]
        return np.asarray(obs), {"track_seed": track_seed}

    def _track_pool(self) -> tuple[Track, np.ndarray]:
        """(the pool's tracks on the device, leading axis P; their CarRacing seeds int64[P]), loaded once."""
        if self._pool is None:
            dataset = load_pool(*self._pool_request)
            self._pool = (jax.tree_util.tree_map(jax.numpy.asarray, dataset.worlds), dataset.seeds)
        return self._pool

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
