"""``worldagent envs``: the registered environments, their options, metrics, descriptors, algorithms, policies and presets."""

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
        f"  descriptors: {descriptor_line(metrics)}",
        *(
            [f"  failure:     {spec.failure} (what reproduce counts as a failure; e.g. atlas --failure, failure-rate --event)"]
            if spec.failure
            else []
        ),
        f"  repairs:     {repair_line(spec)}",
        f"  algorithms:  {algorithms}",
        f"  optimiser:   {spec.optimiser} (strategic and search, unless --optimiser)",
        f"  policies:    {', '.join(spec.scripted) or 'none'} (scripted, for --agent)",
        *([f"  world sets:  {', '.join(spec.world_sets)} (for evaluate worlds --worlds NAME)"] if spec.world_sets else []),
        f"  presets:     {preset_line(spec.presets)}",
    ]
    return "\n".join(lines)


def descriptor_line(metrics) -> str:
    """``total_curvature (default), ..., track_length (for atlas --descriptors)``."""
    named = [f"{name} (default)" if name in metrics.default_descriptors else name for name in metrics.descriptors]
    return f"{', '.join(named)} (for atlas --descriptors)" if named else "none (no failure atlas)"


def repair_line(spec) -> str:
    """``nearest (default): ...; open: ... (for generator train --repair)``: each repair and the first line of its doc."""
    from worldagent.envs.registry import DEFAULT_REPAIR

    def summary(name: str) -> str:
        factory = spec.repair_factory(name)
        doc = (getattr(factory, "__self__", factory).__doc__ or "").strip()
        return doc.splitlines()[0].rstrip(".") if doc else ""

    marked = lambda name: f"{name} (default)" if name == spec.default_repair and name != DEFAULT_REPAIR else name  # noqa: E731
    named = [f"{marked(name)}: {summary(name)}" if summary(name) else marked(name) for name in spec.repair_names]
    return "; ".join(named) + " (for generator train --repair)"


def preset_line(presets) -> str:
    """``paper (10,000 worlds, 10,000 episodes), tiny (...) (for reproduce --preset)``: each preset's dataset and training budget."""
    if not presets:
        return "none (no reproduce run)"
    sizes = lambda budgets: ", ".join(f"{budgets[key]:,} {key}" for key in ("worlds", "episodes") if key in budgets)  # noqa: E731
    return ", ".join(f"{name} ({sizes(budgets)})" if sizes(budgets) else name for name, budgets in presets.items()) + " (for reproduce --preset)"


def envs_command() -> None:
    """List the registered environments with their options, metrics, descriptors, algorithms, scripted policies and presets."""
    from worldagent.envs import registry

    typer.echo("\n\n".join(describe(name) for name in registry.names()))


def register(app: typer.Typer) -> None:
    """Add ``worldagent envs``."""
    app.command("envs")(friendly_errors(envs_command))
