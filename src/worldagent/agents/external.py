"""External agents (paper §4.3, footnote: "also works for rule-based and pre-trained agents").

A ``HostPolicy`` is any agent that is not JAX: a Python callable, an ONNX model or a
Stable-Baselines3 model. It is called from Python once per step on the whole batch of episodes
that the host evaluator (``evaluation/host.py``) steps in lockstep::

    actions = policy(obs, keys)        # obs [E, *obs_shape] (or [E, N, *obs_shape]) -> int32 [E] (or [E, N])

The agent returns integer actions ``[B]`` (``[B, N]`` for N agents) or float logits
``[B, A]`` (``[B, N, A]``); logits are acted on by argmax, or sampled with the episode's key
when ``stochastic`` (``jax.random.categorical``, as a trained actor-critic samples, so a
jitted policy computing the same logits plays the same episodes). Anything else gets a one-line
error naming the shapes expected.

Loaders (``load_callable``, ``load_onnx``, ``load_sb3``) build one from what ``--agent`` names;
``agents.loaders.load_agent`` picks the loader.
"""

from __future__ import annotations

import dataclasses
import importlib
import sys
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import numpy as np

from worldagent.agents.policy import AgentSource, file_hash
from worldagent.errors import WorldagentError


@dataclass(frozen=True)
class HostPolicy:
    """An external agent: ``fn(obs batch numpy) -> actions or logits``, called from Python.

    Attributes:
        fn: the agent; gets float32 or the env's dtype, shape ``[B, *obs_shape]`` (``[B, N, ...]``
            for N agents, or ``[B·N, ...]`` when ``per_agent``).
        num_actions: A, the env's action count (actions are checked against it).
        num_agents: N (1: no agent axis).
        name: for reports and errors.
        source: what the agent is (kind, path, file hash), recorded in the store.
        stochastic: sample logits with the episode keys instead of taking their argmax.
        per_agent: ``fn`` is one agent's model; the N agents' observations are stacked on the batch axis.
        as_float32: observations are cast to float32 (ONNX models take float32).
        home: the directory a callable's module was imported from (workers import it from there).
    """

    fn: Callable[[np.ndarray], Any]
    num_actions: int
    num_agents: int = 1
    name: str = "external agent"
    source: AgentSource | None = None
    stochastic: bool = False
    per_agent: bool = False
    as_float32: bool = False
    home: str | None = None
    host = True
    privileged = False

    def __call__(self, obs: np.ndarray, keys: jax.Array | None = None) -> np.ndarray:
        """int32 actions ``[E]`` (or ``[E, N]``) for observations ``[E, ...]`` and the episodes' ``[E]`` action keys."""
        obs = np.asarray(obs, np.float32) if self.as_float32 else np.asarray(obs)
        batch = len(obs)
        multi = self.num_agents > 1
        fed = obs.reshape(batch * self.num_agents, *obs.shape[2:]) if self.per_agent and multi else obs
        try:
            out = self.fn(fed)
        except WorldagentError:
            raise
        except (Exception, SystemExit) as error:  # the user's code (sys.exit too): say whose, in one line
            raise WorldagentError(f"{self.name} failed on observations of shape {fed.shape} ({fed.dtype}): {one_line(error)}") from None
        out = np.asarray(out)
        if self.per_agent and multi and out.ndim >= 1 and out.shape[0] == batch * self.num_agents:
            out = out.reshape(batch, self.num_agents, *out.shape[1:])
        return self.actions(out, batch, keys)

    def __reduce__(self):
        """Pickled (for Ray workers) by source where it has one: the worker opens the agent again."""
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        if self.source is not None and self.source.kind in REOPENERS:
            return _reopened, ({**fields, "fn": None},)
        return HostPolicy, tuple(fields.values())

    def actions(self, out: np.ndarray, batch: int, keys: jax.Array | None) -> np.ndarray:
        """The agent's output as checked int32 actions: integers as they are, logits by argmax or sampling."""
        shape = (batch,) if self.num_agents == 1 else (batch, self.num_agents)
        expected = f"integer actions {shape} or float logits {(*shape, self.num_actions)} for a batch of {batch}"
        if out.shape == (*shape, self.num_actions) and np.issubdtype(out.dtype, np.floating):
            if not np.all(np.isfinite(out)):
                raise WorldagentError(f"{self.name} returned NaN or infinite logits; check the model.")
            if self.stochastic and keys is not None:
                return np.asarray(_sample(keys, out, self.num_agents))
            return np.argmax(out, axis=-1).astype(np.int32)
        if out.shape != shape:
            raise WorldagentError(f"{self.name} returned an array of shape {out.shape}; expected {expected}.")
        if not (np.issubdtype(out.dtype, np.integer) or out.dtype == bool):
            raise WorldagentError(f"{self.name} returned {out.dtype} actions; expected {expected} (cast actions with .astype(int)).")
        if out.size and (out.min() < 0 or out.max() >= self.num_actions):
            bad = int(out[(out < 0) | (out >= self.num_actions)].flat[0])
            raise WorldagentError(f"{self.name} returned action {bad}; actions are integers in [0, {self.num_actions}).")
        return out.astype(np.int32)


@jax.jit
def _sample_one(keys: jax.Array, logits: jax.Array) -> jax.Array:
    return jax.vmap(jax.random.categorical)(keys, logits).astype(np.int32)


@jax.jit
def _sample_agents(keys: jax.Array, logits: jax.Array) -> jax.Array:
    # per episode key, split over the agents as policy.network_act does
    return jax.vmap(lambda key, per_agent: jax.vmap(jax.random.categorical)(jax.random.split(key, per_agent.shape[0]), per_agent))(
        keys, logits
    ).astype(np.int32)


def _sample(keys: jax.Array, logits: np.ndarray, num_agents: int) -> jax.Array:
    """Sample actions from logits ``[E, A]`` (``[E, N, A]``) with the episodes' keys ``[E]``."""
    return _sample_one(keys, logits) if num_agents == 1 else _sample_agents(keys, logits)


def one_line(error: BaseException) -> str:
    """``Type: first line of the message`` (at most 200 characters), for one-line errors about the user's code."""
    if isinstance(error, SystemExit):
        return f"it called sys.exit({error.code!r})"
    return f"{type(error).__name__}: {(str(error).splitlines() or [''])[0][:200]}"


# -- loaders -------------------------------------------------------------------------------------

# External agents run torch and ONNX Runtime on one intra-op thread. Their batches are small
# MLP forward passes, which more threads barely speed up, while on a busy machine the threads
# contend with JAX's (a Stable-Baselines3 agent ran 5-10x slower with torch's default on 2 cores).
AGENT_THREADS = 1


def is_callable_reference(text: str) -> bool:
    """``module:function`` (dotted names on both sides), e.g. ``mymodule:act``."""
    module, sep, name = text.partition(":")
    return bool(sep) and all(part.isidentifier() for part in (*module.split("."), *name.split(".")))


def load_callable(text: str, env: Any, stochastic: bool = False) -> HostPolicy:
    """``module:function`` importable from the working directory or the Python path, as a ``HostPolicy``.

    The function takes observations ``[B, *obs_shape]`` (``[B, N, *obs_shape]`` for N agents)
    as numpy and returns actions ``[B]`` (``[B, N]``) or logits.
    """
    fn, origin = _import_callable(text)
    source = AgentSource("callable", text, file_hash(Path(origin)) if origin else None)
    home = str(Path(origin).parents[text.partition(":")[0].count(".")]) if origin else None
    return HostPolicy(fn, env.num_actions, env.num_agents, name=f"callable {text}", source=source, stochastic=stochastic, home=home)


def _import_callable(text: str, home: str | None = None) -> tuple[Callable, str | None]:
    """(the function ``module:function`` names, its module's file), importing from ``home`` or the working directory."""
    module_name, _, attribute = text.partition(":")
    where = home or str(Path.cwd())  # `python -m` semantics: modules in the working directory
    if where not in sys.path and not (home is None and "" in sys.path):
        sys.path.insert(0, where)
    try:
        module = importlib.import_module(module_name)
    except ImportError as error:
        if is_missing(module_name, error):
            raise WorldagentError(
                f"cannot import {module_name!r} for agent {text!r} ({error}); run from its directory or add it to PYTHONPATH."
            ) from None
        if isinstance(error, ModuleNotFoundError) and error.name:
            raise WorldagentError(f"agent module {module_name!r} imports {error.name!r}, which is not installed; install it.") from None
        raise WorldagentError(f"agent module {module_name!r} failed to import: {one_line(error)}; fix the module.") from None
    except (Exception, SystemExit) as error:  # a syntax error, or the module's own code raising (or exiting) on import
        raise WorldagentError(f"agent module {module_name!r} failed to import: {one_line(error)}; fix the module.") from None
    fn: Any = module
    for part in attribute.split("."):
        fn = getattr(fn, part, None)
    if not callable(fn):
        raise WorldagentError(f"{module_name} has no callable {attribute!r}; pass module:function with a function obs batch -> actions.")
    return fn, getattr(module, "__file__", None)


def is_missing(module_name: str, error: ImportError) -> bool:
    """Whether ``error`` says ``module_name`` itself (or a package above it) is not found, not something it imports."""
    missing = getattr(error, "name", None)
    return isinstance(error, ModuleNotFoundError) and missing is not None and (module_name + ".").startswith(missing + ".")


def load_onnx(path: str | Path, env: Any, stochastic: bool = False) -> HostPolicy:
    """An ONNX model (extra ``onnx``) taking float32 observations ``[B, *obs_shape]``, as a ``HostPolicy``.

    For N agents the model takes either all agents ``[B, N, *obs_shape]`` or one agent
    ``[B, *obs_shape]`` (then it plays every agent). It returns logits or integer actions.
    """
    path = Path(path).resolve()
    fn, input_shape = _open_onnx(path)
    per_agent = _onnx_layout(path, input_shape, tuple(env.observation_shape), env.num_agents)
    source = AgentSource("onnx", str(path), file_hash(path))
    return HostPolicy(fn, env.num_actions, env.num_agents, f"ONNX {path.name}", source, stochastic, per_agent, as_float32=True)


def _open_onnx(path: Path) -> tuple[Callable, list]:
    """(``obs -> first output`` of the model at ``path``, its input's shape)."""
    if not path.is_file():
        raise WorldagentError(f"no ONNX model at {path}; pass the path of a .onnx file.")
    try:
        import onnxruntime
    except ImportError:
        raise WorldagentError("ONNX agents need onnxruntime: pip install 'worldagent[onnx]'.") from None
    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = AGENT_THREADS
    try:
        session = onnxruntime.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    except Exception as error:
        raise WorldagentError(f"{path} is not a valid ONNX model ({(str(error).splitlines() or [''])[0][:160]}).") from None
    inputs = session.get_inputs()
    if len(inputs) != 1:
        raise WorldagentError(f"{path} has {len(inputs)} inputs; an agent takes one: observations [B, *obs_shape] (float32).")
    feed, output = inputs[0].name, session.get_outputs()[0].name
    return (lambda obs: session.run([output], {feed: obs})[0]), list(inputs[0].shape)


def _onnx_layout(path: Path, shape: list, obs_shape: tuple[int, ...], num_agents: int) -> bool:
    """Whether the model takes one agent's observations (True) or all agents' (False); else a one-line error."""
    fits = lambda want: len(shape) == len(want) + 1 and all(not isinstance(d, int) or d == w for d, w in zip(shape[1:], want))
    if fits(obs_shape):
        return num_agents > 1
    if num_agents > 1 and fits((num_agents, *obs_shape)):
        return False
    wanted = f"[B, {', '.join(map(str, obs_shape))}]" + (f" or [B, {num_agents}, {', '.join(map(str, obs_shape))}]" if num_agents > 1 else "")
    raise WorldagentError(f"{path} takes input of shape {shape}; this env's observations are {wanted} (float32).")


SB3_ALGORITHMS = ("PPO", "A2C", "DQN")  # the Stable-Baselines3 algorithms with discrete actions


def load_sb3(path: str | Path, env: Any, stochastic: bool = False) -> HostPolicy:
    """A Stable-Baselines3 model zip (extra ``sb3``), loaded only because the user named the file.

    The model plays one agent: its observation space must be the env's ``obs_shape``. With
    ``stochastic`` it samples through ``model.predict`` (torch's randomness, not the episode keys).
    """
    path = Path(path).resolve()
    model = _open_sb3(path)
    shape = tuple(model.observation_space.shape or ())
    if shape != tuple(env.observation_shape):
        raise WorldagentError(f"{path} observes shape {shape}; this env's observations are {tuple(env.observation_shape)}.")
    source = AgentSource("sb3", str(path), file_hash(path))
    return HostPolicy(_sb3_act(model, stochastic), env.num_actions, env.num_agents, f"SB3 {path.name}", source, stochastic, env.num_agents > 1)


def _open_sb3(path: Path) -> Any:
    """The Stable-Baselines3 model in ``path`` (trying each discrete-action algorithm)."""
    if not path.is_file():
        raise WorldagentError(f"no Stable-Baselines3 model at {path}; pass the path of a model .zip.")
    if not zipfile.is_zipfile(path):
        raise WorldagentError(f"{path} is not a zip file; pass the .zip a Stable-Baselines3 model's save() writes.")
    try:
        import stable_baselines3
        import torch
    except ImportError:
        raise WorldagentError("Stable-Baselines3 agents need it installed: pip install 'worldagent[sb3]'.") from None
    torch.set_num_threads(AGENT_THREADS)
    errors = []
    for name in SB3_ALGORITHMS:
        try:
            return getattr(stable_baselines3, name).load(str(path), device="cpu")
        except Exception as error:  # the zip names its policy class, not its algorithm: try each
            errors.append(f"{name}: {(str(error).splitlines() or [''])[0][:80]}")
    raise WorldagentError(f"{path} is not a Stable-Baselines3 {'/'.join(SB3_ALGORITHMS)} model ({'; '.join(errors)}).")


def _sb3_act(model: Any, stochastic: bool) -> Callable:
    return lambda obs: model.predict(obs, deterministic=not stochastic)[0]


# A loaded model (an ONNX session, a torch module) does not travel between processes; a worker
# (Ray) opens the agent again from its source instead.
REOPENERS: dict[str, Callable[[dict], Callable]] = {
    "callable": lambda fields: _import_callable(fields["source"].path, fields["home"])[0],
    "onnx": lambda fields: _open_onnx(Path(fields["source"].path))[0],
    "sb3": lambda fields: _sb3_act(_open_sb3(Path(fields["source"].path)), fields["stochastic"]),
}


def _reopened(fields: dict) -> HostPolicy:
    """A ``HostPolicy`` pickled without its function, with its agent opened again from its source."""
    return HostPolicy(**{**fields, "fn": REOPENERS[fields["source"].kind](fields)})
