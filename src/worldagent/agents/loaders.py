"""Turning an ``--agent`` string into a policy: ours (jitted) or an external one (host).

policy = load_agent(registry.get("racing"), "runs/ppo")       # a `worldagent train` run dir
policy = load_agent(spec, "runs/ppo/policy")                   # the saved policy inside it
policy = load_agent(spec, "driver")                            # a scripted policy of the spec (or "scripted/driver")
policy = load_agent(spec, "agent.onnx")                        # an ONNX model (extra `onnx`)
policy = load_agent(spec, "mymodule:act")                      # a Python callable obs batch -> actions
policy = load_agent(spec, "ppo_racing.zip")                    # a Stable-Baselines3 model (extra `sb3`)

Every policy carries its ``source`` (kind, path, file hash), which campaigns record.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from worldagent.agents import external
from worldagent.agents.policy import AgentSource, Policy, file_hash
from worldagent.agents.saved import CONFIG_FILE, PARAMS_FILE, load_policy
from worldagent.envs import registry
from worldagent.errors import WorldagentError

POLICY_DIR = "policy"  # where `worldagent train` saves the agent inside its run directory


def scripted_policy(spec: Any, name: str, options: Mapping[str, Any] | None = None) -> Policy:
    """The spec's scripted policy ``name`` as a ``Policy`` (built for the env of ``options``)."""
    spec = registry.get(spec)
    if name not in spec.scripted:
        known = ", ".join(spec.scripted) or "none"
        raise WorldagentError(f"{spec.name} has no scripted policy {name!r}; its scripted policies: {known}.")
    env, params = spec.make_env(options)
    scripted = spec.scripted[name](env, params)
    return Policy(scripted.params, scripted.act, name, privileged=scripted.privileged, source=AgentSource("scripted", name))


def policy_dir(text: str | Path) -> Path | None:
    """The saved-policy directory ``text`` names (a run dir or the policy dir itself), or None."""
    path = Path(text)
    for candidate in (path / POLICY_DIR, path):
        if (candidate / CONFIG_FILE).is_file():
            return candidate
    return None


def agent_options(spec: Any, agent: Any, given: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The env options to play ``agent`` with: ``given`` first, then those a saved agent recorded
    when it trained (so a ``rays`` racing agent plays ``rays`` with no flag), then the defaults."""
    spec = registry.get(spec)
    directory = policy_dir(agent) if isinstance(agent, (str, Path)) else None
    recorded = {}
    if directory is not None:
        try:
            recorded = json.loads((directory / CONFIG_FILE).read_text()).get("extra", {}).get("options", {})
        except (OSError, ValueError, AttributeError):
            recorded = {}  # load_policy reports a broken file with its remedy
    known = {option.name for option in spec.options}
    # JSON turned tuples (harvest's tagger) into lists
    recorded = {name: tuple(value) if isinstance(value, list) else value for name, value in recorded.items() if name in known}
    return spec.check_options({**recorded, **(given or {})})


def check_observations(spec: Any, directory: Path, obs_shape: tuple[int, ...], options: Mapping[str, Any]) -> None:
    """A saved agent must see the observations these options give; else one line naming the fix."""
    env, _ = spec.make_env(options)
    if tuple(env.observation_shape) != tuple(obs_shape):
        changed = ", ".join(f"{k}={v}" for k, v in options.items())
        raise WorldagentError(
            f"{directory} was trained on observations of shape {tuple(obs_shape)}, but {spec.name} with {changed} gives "
            f"{tuple(env.observation_shape)}; pass the options it trained with (--option NAME=VALUE)."
        )


AGENT_FORMS = (
    "a `worldagent train` run or policy directory, a scripted policy ({scripted}), a .onnx file, a Stable-Baselines3 .zip, or module:function"
)


def load_agent(
    spec: Any, text: str | Path, greedy: bool = False, options: Mapping[str, Any] | None = None, stochastic: bool = False
) -> Policy | external.HostPolicy:
    """The agent ``text`` names: a jitted ``Policy`` (ours) or an external ``HostPolicy``.

    Args:
        spec: the environment (an ``EnvSpec`` or its name); agents must fit its observations and actions.
        text: a ``worldagent train`` run directory (the agent in its ``policy/``), the policy
            directory itself, the name of one of ``spec.scripted``, a ``.onnx`` model, a
            Stable-Baselines3 ``.zip`` or ``module:function`` (see ``agents.external``).
        greedy: saved agents act by argmax (see ``saved.load_policy``).
        options: the env options the agent plays (e.g. harvest's tagger).
        stochastic: external agents that return logits sample them instead of taking the argmax.

    Returns:
        A ``Policy`` (``act(params, obs, key, state) -> action``) or a ``HostPolicy``
        (``obs batch -> actions``), each with its ``source``.
    """
    spec = registry.get(spec)
    text = str(text)
    if text.removeprefix("scripted/") in spec.scripted:  # the explorer's label for it, too
        return scripted_policy(spec, text.removeprefix("scripted/"), options)
    directory = policy_dir(text)
    if directory is not None:
        saved = load_policy(directory, env=spec.name, greedy=greedy)
        check_observations(spec, directory, saved.obs_shape, spec.check_options(options))
        return saved.policy.replace(source=AgentSource("worldagent", str(directory), file_hash(directory / CONFIG_FILE, directory / PARAMS_FILE)))
    suffix = Path(text).suffix.lower()
    if suffix in (".onnx", ".zip"):
        env, _ = spec.make_env(options)
        loader = external.load_onnx if suffix == ".onnx" else external.load_sb3
        return loader(text, env, stochastic)
    if external.is_callable_reference(text) and not Path(text).exists():
        env, _ = spec.make_env(options)
        return external.load_callable(text, env, stochastic)
    forms = AGENT_FORMS.format(scripted=", ".join(spec.scripted) or "none")
    raise WorldagentError(f"agent {text!r} is not {forms}; pass one of those.")
