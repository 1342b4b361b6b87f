"""Particle Racing as a Gymnasium ``VectorEnv``: N envs stepped by one jitted ``vmap``, and the track pool.

``gymnasium.make_vec("worldagent/ParticleRacing-v0", num_envs=N)`` (after ``import worldagent``)
returns a ``ParticleRacingVectorEnv``::

    envs = gymnasium.make_vec("worldagent/ParticleRacing-v0", num_envs=64)
    obs, info = envs.reset(seed=0)                      # obs f32[64, D]
    obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())

Autoreset is ``AutoresetMode.SAME_STEP`` (``metadata["autoreset_mode"]``), the convention of
``core.step_autoreset`` and of Stable-Baselines3's VecEnvs: the step that ends an episode
returns that step's reward, ``terminated`` and ``truncated``, but already the *first*
observation of the next episode; the last observation of the ended one is
``info["final_obs"][i]`` (f32[N, D], meaningful where ``info["_final_obs"]``) and its episode
metrics are ``info["final_info"]`` (``return``, ``crashed``, ``lap_completed``, ``progress``,
``steps``, each [N]). Both keys are present only on steps where some episode ended. No step is
spent on resets, so every step of the batch is a training step.

Each new episode is played on a newly drawn world, inside the same jitted step (no Python loop
over envs):

- a *pool* of CarRacing tracks (default): ``pool_size`` tracks with seeds ``pool_seed ..
  pool_seed + pool_size - 1``, generated once and cached on disk (``track_pool``), or the
  worlds of a ``worldagent dataset`` file passed as ``pool``; a world is drawn uniformly;
- G(z) (``generator=``, a generator directory or a ``Generator``): each new episode plays
  ``G(z)`` for a fresh ``z ~ N(0, I)``. G runs on ``num_envs`` latents at a time into a stock
  that ended episodes draw from, so its cost is one G evaluation per episode, not per step.

Stable-Baselines3 takes its own ``VecEnv`` class, not Gymnasium's: ``to_sb3(envs)`` adapts one
(``PPO("MlpPolicy", to_sb3(envs))``; ``envs/sb3.py``). Training-time respawn
(``params=RacingParams(respawn=True)``) makes every episode last to the lap or the time limit
(``tests/envs/test_sb3.py`` trains SB3's PPO with it).

Harvest has no vector env here: PettingZoo defines no vector API, and a Gymnasium
``VectorEnv`` needs one scalar reward per sub-env where Harvest gives one per agent (``[N, 4]``);
folding agents into the env axis (SuperSuit's approach) would make the agents' shared world and
simultaneous moves look like independent envs. Batched harvest training goes through the pure
functions (``core.step_autoreset`` under ``vmap``) instead.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from worldagent.envs.core import check_actions
from worldagent.envs.racing.env import ROUTE_SCALE, ParticleRacing, RacingParams, RacingState
from worldagent.envs.racing.world import Track
from worldagent.errors import WorldagentError
from worldagent.worlds.dataset import WorldDataset, make_dataset

POOL_SIZE = 256  # tracks in the default pool: ~1 s to generate once, 2 MB on disk
POOL_SEED = 0
ROUTE_REACH = 2.0  # normalised units: a bound on how far ahead a route point can be, with margin


# -- the track pool ---------------------------------------------------------------------------


def cache_directory(cache_dir: Path | str | None = None) -> Path:
    """Where generated pools are kept: ``cache_dir``, else ``$XDG_CACHE_HOME/worldagent``, else ``~/.cache/worldagent``."""
    if cache_dir is not None:
        return Path(cache_dir)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "worldagent"


def track_pool(size: int = POOL_SIZE, seed: int = POOL_SEED, cache_dir: Path | str | None = None) -> WorldDataset:
    """``size`` CarRacing tracks with seeds ``seed .. seed + size - 1``, generated once and cached.

    The pool is a ``worldagent`` dataset file (``racing-pool-<size>-seed<seed>.npz`` in
    ``cache_directory(cache_dir)``, read with ``allow_pickle=False``) and is kept in memory after
    the first call, so later envs in the same process get it for free. A corrupted cache file is
    generated again.

    Args:
        size: P, number of tracks (>= 1).
        seed: the first track's CarRacing seed (>= 0).
        cache_dir: the cache folder; None for ``$XDG_CACHE_HOME/worldagent`` or ``~/.cache/worldagent``.

    Returns:
        The pool as a ``WorldDataset``: ``worlds`` a ``Track`` with leading axis P, ``seeds`` int64[P].
    """
    check_pool_arguments(size, seed)
    path = cache_directory(cache_dir).resolve() / f"racing-pool-{int(size)}-seed{int(seed)}.npz"
    return _cached_pool(path, int(size), int(seed))


def check_pool_arguments(size: Any, seed: Any) -> None:
    """Raise ``WorldagentError`` unless ``size`` is an integer >= 1 and ``seed`` an integer >= 0."""
    for name, value, least in (("pool_size", size, 1), ("pool_seed", seed, 0)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
            raise WorldagentError(f"{name}={value!r}; pass an integer >= {least}.")


@functools.lru_cache(maxsize=8)
def _cached_pool(path: Path, size: int, seed: int) -> WorldDataset:
    """The pool at ``path``, generated and written there first if missing or unreadable."""
    if path.is_file():
        try:
            return WorldDataset.load(path, env="racing")
        except WorldagentError:
            pass  # a cache file is disposable: make it again
    pool = make_dataset("racing", size, seed, progress=False)
    pool.save(path)
    return pool


def load_pool(
    pool: WorldDataset | Path | str | None = None, size: int = POOL_SIZE, seed: int = POOL_SEED, cache_dir: Path | str | None = None
) -> WorldDataset:
    """The worlds new episodes are drawn from: ``pool`` (a racing dataset or its file), else ``track_pool(size, seed)``.

    Returns:
        A racing ``WorldDataset`` whose worlds (leading axis P) have all passed ``Track.validate``.
    """
    if pool is None:
        return track_pool(size, seed, cache_dir)
    dataset = pool if isinstance(pool, WorldDataset) else WorldDataset.load(pool, env="racing")
    if dataset.env != "racing":
        raise WorldagentError(f"pool holds {dataset.env} worlds; pass a racing dataset (`worldagent dataset racing`).")
    dataset.worlds.validate()
    return dataset


def observation_space(env: ParticleRacing) -> spaces.Box:
    """``Box(W·W + 4 + 2·R)`` of one Particle Racing observation (window, position, velocity, route)."""
    cells, route = env.window * env.window, 2 * len(env.route)
    reach = ROUTE_REACH / ROUTE_SCALE  # route points are at most ~0.5 units away
    low = np.concatenate([np.zeros(cells), [-1.5, -1.5, -1.0, -1.0], np.full(route, -reach)]).astype(np.float32)
    high = np.concatenate([np.ones(cells), [1.5, 1.5, 1.0, 1.0], np.full(route, reach)]).astype(np.float32)
    return spaces.Box(low=low, high=high, dtype=np.float32)


# -- where new episodes' worlds come from (pytrees, passed into the jitted step) ----------------


def take(worlds: Any, index: jax.Array) -> Any:
    """The worlds at ``index`` i32[N] of a batch of worlds (leading axis P) -> leading axis N."""
    return jax.tree_util.tree_map(lambda leaf: leaf[index], worlds)


@struct.dataclass
class PoolSource:
    """Worlds drawn uniformly, with replacement, from a fixed pool.

    Attributes:
        worlds: the pool, a ``Track`` with leading axis P.
    """

    worlds: Track

    def start(self, key: jax.Array, num_envs: int) -> tuple[Track, None]:
        """(N worlds for the first episodes, the source's carried stock: none)."""
        return self.draw(key, None, jnp.ones(num_envs, bool))

    def draw(self, key: jax.Array, stock: None, done: jax.Array) -> tuple[Track, None]:
        """N fresh worlds (used where ``done`` bool[N]) and the unchanged stock."""
        index = jax.random.randint(key, done.shape, 0, self.worlds.centreline.shape[0])
        return take(self.worlds, index), stock


@struct.dataclass
class GeneratorStock:
    """Worlds G has made ahead of need: ``worlds`` (leading axis N), of which the first ``used`` are spent."""

    worlds: Track
    used: jax.Array


@struct.dataclass
class GeneratorSource:
    """Worlds ``G(z)``, one fresh ``z ~ N(0, I)`` per new episode.

    Attributes:
        generator: a racing ``Generator``, ``G(z f32[B, latent_dim]) -> Track[B]``.
    """

    generator: Any

    def generate(self, key: jax.Array, count: int) -> Track:
        """``count`` worlds G(z) for z ~ N(0, I) f32[count, latent_dim]."""
        return self.generator(jax.random.normal(key, (count, self.generator.latent_dim)))

    def start(self, key: jax.Array, num_envs: int) -> tuple[Track, GeneratorStock]:
        """(N worlds for the first episodes, a full stock of N more)."""
        key_now, key_stock = jax.random.split(key)
        return self.generate(key_now, num_envs), GeneratorStock(self.generate(key_stock, num_envs), jnp.int32(0))

    def draw(self, key: jax.Array, stock: GeneratorStock, done: jax.Array) -> tuple[Track, GeneratorStock]:
        """Hand the next unspent stock worlds to the envs where ``done`` bool[N], refilling the stock first if short."""
        num_envs = done.shape[0]
        count = done.sum(dtype=jnp.int32)
        refill = lambda: GeneratorStock(self.generate(key, num_envs), jnp.int32(0))  # noqa: E731
        stock = jax.lax.cond(stock.used + count > num_envs, refill, lambda: stock)
        slot = jnp.clip(stock.used + jnp.cumsum(done, dtype=jnp.int32) - 1, 0, num_envs - 1)  # the k-th ended env takes slot used + k
        return take(stock.worlds, slot), stock.replace(used=stock.used + count)


# -- the batched, autoresetting step (pure; jitted by the VectorEnv) ----------------------------


@struct.dataclass
class VectorState:
    """All N envs: their states (leading axis N, worlds included), the source's stock, the RNG key."""

    envs: RacingState
    stock: Any
    key: jax.Array


def reset_all(env: ParticleRacing, source: Any, params: RacingParams, key: jax.Array, num_envs: int) -> tuple[jax.Array, VectorState]:
    """Start N episodes on worlds from ``source``.

    Returns:
        (obs f32[N, D], the ``VectorState``).
    """
    key_worlds, key_reset, key_next = jax.random.split(key, 3)
    worlds, stock = source.start(key_worlds, num_envs)
    obs, states = jax.vmap(env.reset, in_axes=(0, 0, None))(jax.random.split(key_reset, num_envs), worlds, params)
    return obs, VectorState(states, stock, key_next)


def step_all(env: ParticleRacing, source: Any, params: RacingParams, state: VectorState, actions: jax.Array) -> tuple[VectorState, dict]:
    """One step of all N envs; envs whose episode ended start a new one on a new world (SAME_STEP).

    Args:
        actions: i32[N].

    Returns:
        (state, outputs): ``outputs`` maps ``obs`` f32[N, D] (the new episode's first where it
        ended), ``final_obs`` f32[N, D] (the step's own), ``reward`` f32[N], ``terminated`` and
        ``truncated`` bool[N], ``info/<name>`` (the step's info, [N]) and ``final_info/<name>``
        (the episode metrics of the envs' episodes up to this step, [N]).
    """
    num_envs = actions.shape[0]
    key_step, key_worlds, key_reset, key_next = jax.random.split(state.key, 4)
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))
    final_obs, stepped, reward, terminated, truncated, info = step(jax.random.split(key_step, num_envs), state.envs, actions, params)
    done = jnp.logical_or(terminated, truncated)
    worlds, stock = source.draw(key_worlds, state.stock, done)
    reset_obs, fresh = jax.vmap(env.reset, in_axes=(0, 0, None))(jax.random.split(key_reset, num_envs), worlds, params)
    pick = lambda new, old: jnp.where(done.reshape(-1, *([1] * (old.ndim - 1))), new, old)  # noqa: E731
    envs = jax.tree_util.tree_map(pick, fresh, stepped)
    outputs = {"obs": pick(reset_obs, final_obs), "final_obs": final_obs, "reward": reward, "terminated": terminated, "truncated": truncated}
    outputs.update({f"info/{name}": value for name, value in info.items()})
    outputs.update({f"final_info/{name}": value for name, value in env.metrics(stepped).items()})
    return VectorState(envs, stock, key_next), outputs


def pack(outputs: dict[str, jax.Array]) -> jax.Array:
    """f32[N, C]: the arrays of ``outputs`` (each [N, ...]) side by side in name order, so the host fetches one array.

    Integers must stay below 2**24 and are exact (step counts); booleans become 0 / 1.
    """
    columns = [outputs[name].reshape(outputs[name].shape[0], -1).astype(jnp.float32) for name in sorted(outputs)]
    return jnp.concatenate(columns, axis=1)


def packed_columns(layout: dict[str, jax.ShapeDtypeStruct]) -> list[tuple[str, slice, tuple[int, ...], np.dtype]]:
    """Where ``pack`` put each output of ``layout`` (its shapes and dtypes): (name, columns, shape, dtype), in name order."""
    columns, start = [], 0
    for name, like in sorted(layout.items()):
        width = int(np.prod(like.shape[1:], dtype=int))
        columns.append((name, slice(start, start + width), tuple(like.shape), np.dtype(like.dtype)))
        start += width
    return columns


def unpack(packed: np.ndarray, columns: list[tuple[str, slice, tuple[int, ...], np.dtype]]) -> dict[str, np.ndarray]:
    """The inverse of ``pack``: ``packed`` f32[N, C] -> the named arrays at ``columns`` (``packed_columns``).

    Float arrays are views of ``packed``; the caller passes a copy it may hand out.
    """
    arrays = {}
    for name, where, shape, dtype in columns:
        column = packed[:, where].reshape(shape)
        arrays[name] = column if dtype == column.dtype else column.astype(dtype)
    return arrays


# -- the Gymnasium VectorEnv ----------------------------------------------------------------------


def _packed_step(env: ParticleRacing, source: Any, params: RacingParams, state: VectorState, actions: jax.Array) -> tuple[VectorState, jax.Array]:
    """``step_all`` with its outputs packed into one f32[N, C] array (each output costs a host transfer)."""
    state, outputs = step_all(env, source, params, state, actions)
    return state, pack(outputs)


@functools.lru_cache(maxsize=8)
def _compiled(env: ParticleRacing):
    """Jitted ``reset_all`` and packed ``step_all``, shared by every vector env over the same env."""
    return jax.jit(functools.partial(reset_all, env), static_argnums=(3,)), jax.jit(functools.partial(_packed_step, env), donate_argnums=(2,))


class ParticleRacingVectorEnv(gymnasium.vector.VectorEnv):
    """``num_envs`` Particle Racing envs in one jitted ``vmap``; a Gymnasium ``VectorEnv`` (SAME_STEP autoreset).

    Spaces: ``single_observation_space`` is ``Box(W·W + 4 + 2·R)`` (as ``ParticleRacingGym``),
    ``observation_space`` its batch ``[N, D]``; ``single_action_space`` is ``Discrete(4)``,
    ``action_space`` ``MultiDiscrete([4] * N)``. ``step`` returns numpy arrays: obs f32[N, D],
    reward f32[N], terminated / truncated bool[N], and ``info`` with ``crashed``,
    ``lap_completed``, ``progress`` (each [N], of this step) plus, when an episode ended,
    ``final_obs`` / ``final_info`` and their masks (see the module docstring).

    Args:
        num_envs: N, envs stepped together (>= 1).
        pool_size: tracks in the generated pool (ignored with ``pool`` or ``generator``).
        pool: a racing ``worldagent dataset`` file (or ``WorldDataset``) to draw worlds from
            instead of the generated pool.
        generator: a generator directory or ``Generator``: worlds are G(z), z ~ N(0, I), one per episode.
        params: the env's ``RacingParams`` (e.g. ``RacingParams(max_steps=100)``).
        window: side of the observation's road window, 0 for none (see ``ParticleRacing``).
        pool_seed: the first CarRacing seed of the generated pool.
        cache_dir: where the generated pool is cached (default ``$XDG_CACHE_HOME/worldagent``
            or ``~/.cache/worldagent``).
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(
        self,
        num_envs: int = 1,
        *,
        pool_size: int = POOL_SIZE,
        pool: WorldDataset | Path | str | None = None,
        generator: Any = None,
        params: RacingParams | None = None,
        window: int = 0,
        pool_seed: int = POOL_SEED,
        cache_dir: Path | str | None = None,
    ):
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise WorldagentError(f"num_envs={num_envs!r}; pass an integer >= 1.")
        if params is not None and not isinstance(params, RacingParams):
            raise WorldagentError(f"params is a {type(params).__name__}; pass RacingParams (e.g. RacingParams(max_steps=100)).")
        self.num_envs = int(num_envs)
        self.env = ParticleRacing(window=window)
        self.params = params or self.env.default_params
        self.source = _world_source(pool, generator, pool_size, pool_seed, cache_dir)
        self.single_observation_space = observation_space(self.env)
        self.single_action_space = spaces.Discrete(self.env.num_actions)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._params = jax.tree_util.tree_map(jnp.asarray, self.params)  # on the device once, not at every step
        self._reset, self._step = _compiled(self.env)
        self._columns = packed_columns(self._output_layout())
        self._state: VectorState | None = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start N new episodes; ``seed`` (an int) makes this and every later step reproducible.

        Returns:
            (obs f32[N, D], info ``{}``).
        """
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))):
            raise ValueError(f"seed={seed!r}; pass one integer (the envs' keys are split from it) or None.")
        if options:
            raise ValueError(f"options {sorted(options)} are not supported; call reset(seed=...) without options.")
        super().reset(seed=seed)
        key = jax.random.key(int(self.np_random.integers(2**63 - 1)))
        obs, self._state = self._reset(self.source, self._params, key, self.num_envs)
        return np.array(obs), {}

    def step(self, actions):
        """Step all N envs with ``actions`` int[N]; ended episodes restart on new worlds at once (SAME_STEP).

        Returns:
            (obs f32[N, D], reward f32[N], terminated bool[N], truncated bool[N], info dict).
        """
        if self._state is None:
            raise RuntimeError("call reset() before step().")
        actions = check_actions(actions, self.env.num_actions, (self.num_envs,)).astype(np.int32)
        self._state, packed = self._step(self.source, self._params, self._state, actions)
        out = unpack(np.array(packed), self._columns)  # a copy: the caller may write into the arrays
        info = {name.removeprefix("info/"): value for name, value in out.items() if name.startswith("info/")}
        done = np.logical_or(out["terminated"], out["truncated"])
        if done.any():
            final_info = {name.removeprefix("final_info/"): value for name, value in out.items() if name.startswith("final_info/")}
            info.update(final_obs=out["final_obs"], _final_obs=done, final_info=final_info, _final_info=done)
        return out["obs"], out["reward"], out["terminated"], out["truncated"], info

    def _output_layout(self) -> dict[str, jax.ShapeDtypeStruct]:
        """Names, shapes and dtypes of ``step_all``'s outputs, to unpack what ``_packed_step`` packed."""
        _, state = jax.eval_shape(self._reset, self.source, self._params, jax.random.key(0), self.num_envs)
        actions = jax.ShapeDtypeStruct((self.num_envs,), jnp.int32)
        return jax.eval_shape(functools.partial(step_all, self.env), self.source, self._params, state, actions)[1]

    @property
    def worlds(self) -> Track | None:
        """The N worlds being played (a ``Track`` with leading axis N), None before ``reset``."""
        return None if self._state is None else self._state.envs.world

    def close_extras(self, **kwargs) -> None:
        self._state = None


def _world_source(pool, generator, pool_size: int, pool_seed: int, cache_dir) -> PoolSource | GeneratorSource:
    """The source of new episodes' worlds: G(z) if ``generator`` is given, else the pool."""
    if generator is None:
        return PoolSource(jax.tree_util.tree_map(jnp.asarray, load_pool(pool, pool_size, pool_seed, cache_dir).worlds))
    if pool is not None:
        raise WorldagentError("pass either pool= or generator=, not both: a generator draws its own worlds.")
    if isinstance(generator, (str, Path)):
        from worldagent.worlds.generator import load_generator

        generator = load_generator(generator)[0]
    if getattr(generator, "env", None) != "racing":
        raise WorldagentError(
            f"generator= is not a racing generator ({getattr(generator, 'env', type(generator).__name__)}); train one on racing worlds."
        )
    return GeneratorSource(generator)


# -- Stable-Baselines3 -----------------------------------------------------------------------------


def split_info(info: dict, num_envs: int) -> list[dict]:
    """Gymnasium's batched info (arrays [N], masked by ``_name`` keys, nested dicts) as one dict per env."""
    infos: list[dict] = [{} for _ in range(num_envs)]
    for name, value in info.items():
        if name.startswith("_"):
            continue
        mask = np.asarray(info.get(f"_{name}", np.ones(num_envs, bool)), bool)
        per_env = split_info(value, num_envs) if isinstance(value, dict) else value
        for index in np.flatnonzero(mask):
            infos[index][name] = per_env[index]
    return infos


def sb3_infos(info: dict, terminated: np.ndarray, truncated: np.ndarray) -> list[dict]:
    """One SB3 info dict per env: the step's info, and for ended episodes ``terminal_observation`` and ``TimeLimit.truncated``."""
    ended = {name: value for name, value in info.items() if name in ("final_obs", "_final_obs")}
    infos = split_info({name: value for name, value in info.items() if name not in ended}, len(terminated))
    for index in np.flatnonzero(np.logical_or(terminated, truncated)):
        infos[index]["terminal_observation"] = ended["final_obs"][index]
        infos[index]["TimeLimit.truncated"] = bool(truncated[index] and not terminated[index])
    return infos


def to_sb3(venv: gymnasium.vector.VectorEnv):
    """``venv`` (e.g. ``gymnasium.make_vec("worldagent/ParticleRacing-v0", ...)``) as a Stable-Baselines3 ``VecEnv``.

    SB3 refuses a Gymnasium ``VectorEnv`` ("not a Gymnasium environment"); this one it trains
    on: ``PPO("MlpPolicy", to_sb3(venv))``. It is wrapped in SB3's ``VecMonitor`` so training logs
    episode returns. See ``envs/sb3.py``; needs the ``sb3`` extra.
    """
    try:
        from worldagent.envs.sb3 import monitored
    except ImportError as error:
        if error.name is None or not error.name.startswith(("stable_baselines3", "torch")):
            raise
        missing = error.name.partition(".")[0]
        raise WorldagentError(f"to_sb3 needs Stable-Baselines3 ({missing} is missing): pip install 'worldagent[sb3]'.") from None
    return monitored(venv)
