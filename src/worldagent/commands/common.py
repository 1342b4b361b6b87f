"""What every command shares: the error wrapper, the console, env / agent / campaign resolution.

Command modules in this package define ``register(app)``; ``worldagent.cli`` calls each of them, so
a new command is a new module here and never an edit to a shared file.
"""

from __future__ import annotations

import functools
from pathlib import Path

import typer
from rich.console import Console
from rich.markup import escape

from worldagent.errors import WorldagentError

console = Console(stderr=True, soft_wrap=True)  # never break a message across lines
ENV_HELP = "Environment: racing or harvest."


def friendly_errors(command):
    """Decorator: report ``WorldagentError`` as one line on stderr and exit with code 2."""

    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        try:
            return command(*args, **kwargs)
        except WorldagentError as error:
            console.print(f"[red]error:[/red] {escape(str(error))}", soft_wrap=True)  # one line, no markup
            raise typer.Exit(code=2) from None

    return wrapper


def env_and_params(env: str, tagger: list[int]):
    """The env object and its params; harvest agents listed in ``tagger`` may TAG (§6.2.2)."""
    if env == "racing":
        from worldagent.envs.racing.env import ParticleRacing

        if tagger:
            raise WorldagentError("--tagger applies to harvest only.")
        racing = ParticleRacing()
        return racing, racing.default_params
    if env == "harvest":
        from worldagent.envs.harvest import Harvest, make_params

        if any(not 0 <= i < 4 for i in tagger):
            raise WorldagentError(f"--tagger {tagger}: agents are numbered 0 to 3.")
        return Harvest(), make_params(can_tag=[i in tagger for i in range(4)])
    raise WorldagentError(f"unknown environment {env!r}; use racing or harvest.")


def agent_policy(env: str, spec: str, greedy: bool):
    """A saved agent (its directory, or the `train` run directory holding it), or a scripted policy by name."""
    from worldagent.agents.policy import CONFIG_FILE, load_policy, scripted_policy

    path = Path(spec)
    if path.is_dir():
        found = next((p for p in (path, path / "policy", path / "agents") if (p / CONFIG_FILE).exists()), path)
        return load_policy(found, env=env, greedy=greedy).policy
    return scripted_policy(env, spec)


def campaign(env, agent, generator, objective, maximize, optimiser, budget, repeats, seed, out, name, resume, tagger, greedy, quiet, config=None):
    """Run one campaign from CLI options; returns its evaluations and spec."""
    from worldagent.search.campaign import CampaignSpec, run_campaign
    from worldagent.search.objectives import LatentObjective, Objective, metric_name
    from worldagent.search.optimisers import OptimiserConfig
    from worldagent.store import RunStore
    from worldagent.worlds.generator import load_generator

    target = Objective(env, metric_name(env, objective), maximize)
    env_obj, params = env_and_params(env, tagger)
    policy = agent_policy(env, agent, greedy)
    G, _, _ = load_generator(generator)
    evaluate = LatentObjective(target, env_obj, policy, G, repeats, params)
    spec = CampaignSpec(name, env, target.metric, maximize, optimiser, budget, seed, G.latent_dim, config or OptimiserConfig())
    with RunStore(out) as store:
        return run_campaign(store, spec, evaluate, resume=resume, progress=not quiet), spec


AGENT_HELP = "A `worldagent train` run directory (or the agent directory in it), or a scripted policy: driver (racing), random or greedy (harvest)."
