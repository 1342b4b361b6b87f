"""``worldagent envs``: the registered environments, their options, metrics, algorithms and policies."""

from __future__ import annotations

import typer

from worldagent.commands.console import friendly_errors


def describe(name: str) -> str:
    """A few lines on one registered environment (what ``worldagent envs`` prints for it)."""
    from worldagent.envs import registry

    spec = registry.get(name)
    metrics = spec.metrics
    aliases = ", ".join(f"{alias} = {target}" for alias, target in metrics.aliases.items())
    options = "; ".join(f"{o.name} ({o.help}; default {o.default!r})" for o in spec.options) or "none"
    algorithms = ", ".join(f"{a} (default)" if a == spec.algorithms[0] else a for a in spec.algorithms) or "none"
    lines = [
        f"{spec.name}: {spec.description}",
        f"  options:     {options}",
        f"  metrics:     {', '.join(metrics.names)} (main: {metrics.main}, also called reward)",
        *([f"  aliases:     {aliases}"] if aliases else []),
        f"  algorithms:  {algorithms}",
        f"  policies:    {', '.join(spec.scripted) or 'none'} (scripted, for --agent)",
    ]
    return "\n".join(lines)


def envs_command() -> None:
    """List the registered environments with their options, metrics, algorithms and scripted policies."""
    from worldagent.envs import registry

    typer.echo("\n\n".join(describe(name) for name in registry.names()))


def register(app: typer.Typer) -> None:
    """Add ``worldagent envs``."""
    app.command("envs")(friendly_errors(envs_command))
