"""A Gymnasium ``VectorEnv`` (same-step autoreset) as a Stable-Baselines3 ``VecEnv``.

SB3 takes either one ``gymnasium.Env`` (which it wraps in its own ``DummyVecEnv``) or its own
``VecEnv``; a Gymnasium ``VectorEnv`` is neither, so ``PPO("MlpPolicy", make_vec(...))`` refuses
it. ``SB3VecEnv`` speaks SB3's protocol over the Gymnasium batch, keeping the one jitted step::

    from worldagent.envs.vector import to_sb3
    venv = to_sb3(gymnasium.make_vec("worldagent/ParticleRacing-v0", num_envs=16))
    PPO("MlpPolicy", venv).learn(50_000)

Both libraries end an episode the same way (SAME_STEP: the step that ends it already returns the
next episode's first observation), so the translation is per step, with no extra env step:
Gymnasium's ``info["final_obs"][i]`` becomes SB3's ``infos[i]["terminal_observation"]`` (what
PPO bootstraps a truncated episode's value from), and a truncation that is not a termination
sets ``infos[i]["TimeLimit.truncated"]``. The N envs are one jitted batch, so attributes are the
batch's (``get_attr`` gives the same value for each env) and per-env methods do not exist.

This module imports ``stable_baselines3``: import it only through ``vector.to_sb3``. The info
translation is in ``vector`` (``split_info``, ``sb3_infos``), testable without SB3.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from stable_baselines3.common.vec_env import VecEnv, VecMonitor

from worldagent.envs.vector import sb3_infos, split_info
from worldagent.errors import WorldagentError


class SB3VecEnv(VecEnv):
    """SB3's ``VecEnv`` protocol over a Gymnasium ``VectorEnv`` with same-step autoreset.

    Args:
        venv: the Gymnasium vector env (``gymnasium.make_vec(...)``); its spaces become SB3's
            per-env spaces (``single_observation_space``, ``single_action_space``).
    """

    def __init__(self, venv: VectorEnv):
        mode = venv.metadata.get("autoreset_mode")
        if mode != AutoresetMode.SAME_STEP:
            raise WorldagentError(
                f"{type(venv.unwrapped).__name__} resets with {mode}; to_sb3 takes same-step autoreset envs "
                "(for others, give SB3 its own: stable_baselines3.common.env_util.make_vec_env)."
            )
        self.venv = venv
        self._actions: np.ndarray | None = None
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)

    def reset(self) -> np.ndarray:
        """Start every episode; the seed SB3 was given (``seed()``, ``PPO(seed=...)``) seeds the whole batch."""
        seed = self._seeds[0]
        options = self._options[0] or None
        obs, info = self.venv.reset(seed=seed, options=options)
        self.reset_infos = split_info(info, self.num_envs)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict]]:
        """(obs [N, ...], rewards f32[N], dones bool[N], one info dict per env) in SB3's convention."""
        if self._actions is None:
            raise RuntimeError("call step_async(actions) before step_wait().")
        obs, reward, terminated, truncated, info = self.venv.step(self._actions)
        self._actions = None
        return obs, np.asarray(reward, np.float32), np.logical_or(terminated, truncated), sb3_infos(info, terminated, truncated)

    def close(self) -> None:
        self.venv.close()

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        """The batch's attribute, once per env of ``indices`` (an AttributeError where it has none)."""
        return [getattr(self.venv, attr_name)] * len(list(self._get_indices(indices)))

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        """Set the batch's attribute (the envs share it: ``indices`` must cover all of them)."""
        self._whole_batch(indices, f"set_attr({attr_name!r})")
        setattr(self.venv, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: Any = None, **method_kwargs) -> list[Any]:
        raise WorldagentError(f"the {self.num_envs} envs are one jitted batch with no per-env {method_name!r}; call it on the Gymnasium vector env.")

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        """No env is wrapped (there are no per-env objects to wrap); episode statistics come from ``VecMonitor``."""
        return [False] * len(list(self._get_indices(indices)))

    def _whole_batch(self, indices: Any, what: str) -> None:
        if sorted(self._get_indices(indices)) != list(range(self.num_envs)):
            raise WorldagentError(f"{what} on some envs only: the {self.num_envs} envs are one batch; pass indices=None.")


def monitored(venv: VectorEnv) -> VecMonitor:
    """``SB3VecEnv(venv)`` in SB3's ``VecMonitor``, so training logs episode returns and lengths."""
    return VecMonitor(SB3VecEnv(venv))
