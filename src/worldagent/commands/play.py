"""``worldagent play ENV``: play episodes of an agent on one generated world and draw them (PNG)."""

from __future__ import annotations

from pathlib import Path

import typer

from worldagent.commands.console import console, friendly_errors
from worldagent.commands.options import AGENT_HELP, PICTURE_CAP, check_counts, check_seed, env_argument, given_options, option_flag
from worldagent.errors import WorldagentError
from worldagent.files import check_writable


def play_episodes(env: str, agent: str, seed: int, key: int, episodes: int, out: Path, options: list[str], greedy: bool = False):
    """Replay ``episodes`` episodes of ``agent`` on generated world ``seed`` and draw them to ``out``.

    Returns:
        (the PNG's path, the episodes' metrics {name: f[E]}).
    """
    import jax
    import numpy as np

    from worldagent.agents.loaders import agent_options, load_agent
    from worldagent.envs import registry
    from worldagent.evaluation.trajectories import replay
    from worldagent.files import write_atomically
    from worldagent.reports.figures import _pyplot

    spec = registry.get(env)
    if out.suffix.lower() != ".png":
        raise WorldagentError(f"cannot draw episodes as {out.suffix or 'a file without extension'}; use .png.")
    check_counts(caps={"episodes": PICTURE_CAP}, episodes=episodes)
    check_seed(seed)
    check_seed(key, "--key")
    check_writable(out, folder=False)
    if spec.pictures.episodes is None:
        raise WorldagentError(f"{spec.name} registers no trajectory picture (pictures.episodes); it cannot be drawn here.")
    parsed = agent_options(spec, agent, given_options(env, options))
    env_obj, params = spec.make_env(parsed)
    policy = load_agent(spec, agent, greedy=greedy, options=parsed)
    world = jax.tree_util.tree_map(lambda leaf: np.asarray(leaf)[0], spec.generate(np.array([seed], np.int64)))
    played = replay(spec, env_obj, policy, world, jax.random.split(jax.random.key(key), episodes), params)
    plt = _pyplot()
    figure, axis = plt.subplots(figsize=(6, 6.4), dpi=120)
    spec.pictures.episodes(axis, world, played)
    axis.set_title(f"{spec.name} world {seed}: {agent}, {episodes} episode{'s' if episodes != 1 else ''}", fontsize=9)
    axis.set_xticks([])
    axis.set_yticks([])
    path = write_atomically(out, lambda tmp: figure.savefig(tmp, format="png", bbox_inches="tight"))
    plt.close(figure)
    return path, played.metrics


def summary_line(env: str, metrics: dict) -> str:
    """``return 812.3, steps 402 (mean of 1 episode), 0/1 episodes crashed``."""
    import numpy as np

    from worldagent.envs import registry

    spec = registry.get(env)
    shown = [name for name in (spec.metrics.main, *spec.metrics.highlighted, "steps") if name in metrics]
    count = len(next(iter(metrics.values()))) if metrics else 0
    parts = ", ".join(f"{name} {np.mean(metrics[name]):.4g}" for name in dict.fromkeys(shown))
    note = spec.episode_note(metrics) if spec.episode_note else ""
    return f"{parts} (mean of {count} episode{'s' if count != 1 else ''}){note}"


def register(app: typer.Typer) -> None:
    """Add ``worldagent play``."""

    @app.command()
    @friendly_errors
    def play(
        env: str = env_argument(),
        policy: str = typer.Option(..., "--policy", help=AGENT_HELP),
        seed: int = typer.Option(0, "--seed", help="Generator seed of the world to play."),
        episodes: int = typer.Option(1, "--episodes", help=f"Episodes to play and draw (at most {PICTURE_CAP})."),
        key: int = typer.Option(0, "--key", help="Seed of the episodes' randomness."),
        out: Path = typer.Option(Path("episodes.png"), "--out", help="PNG file to write."),
        option: list[str] = option_flag(),
        greedy: bool = typer.Option(False, "--greedy", help="Trained actor-critics act by argmax instead of sampling."),
    ) -> None:
        """Play an agent (scripted or trained) on one generated world and draw its trajectories."""
        path, metrics = play_episodes(env, policy, seed, key, episodes, out, option, greedy)
        console.print(f"{summary_line(env, metrics)} -> {path}")
