"""Turning an ``--agent`` string into a ``Policy``: a training run, a saved policy, or a scripted one.

policy = load_agent(registry.get("racing"), "runs/ppo")       # a `worldagent train` run dir
policy = load_agent(spec, "runs/ppo/policy")                   # the saved policy inside it
policy = load_agent(spec, "driver")                            # a scripted policy of the spec
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from worldagent.agents.policy import Policy
from worldagent.agents.saved import CONFIG_FILE, load_policy
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
    return Policy(scripted.params, scripted.act, name, privileged=scripted.privileged)


def policy_dir(text: str | Path) -> Path | None:
    """The saved-policy directory ``text`` names (a run dir or the policy dir itself), or None."""
    path = Path(text)
    for candidate in (path / POLICY_DIR, path):
        if (candidate / CONFIG_FILE).is_file():
            return candidate
    return None


def load_agent(spec: Any, text: str | Path, greedy: bool = False, options: Mapping[str, Any] | None = None) -> Policy:
    """The agent ``text`` names, as a ``Policy``.

    Args:
        spec: the environment (an ``EnvSpec`` or its name); saved agents must be for it.
        text: a ``worldagent train`` run directory (the agent in its ``policy/``), the policy
            directory itself, or the name of one of ``spec.scripted``.
        greedy: saved agents act by argmax (see ``saved.load_policy``).
        options: the env options scripted policies are built for (e.g. harvest's tagger).

    Returns:
        A ``Policy``: ``act(params, obs, key, state) -> action``.
    """
    spec = registry.get(spec)
    text = str(text)
    if text in spec.scripted:
        return scripted_policy(spec, text, options)
    directory = policy_dir(text)
    if directory is not None:
        return load_policy(directory, env=spec.name, greedy=greedy).policy
    known = ", ".join(spec.scripted) or "none"
    raise WorldagentError(f"agent {text!r} is neither a run or policy directory (holding {CONFIG_FILE}) nor a scripted {spec.name} policy ({known}).")
