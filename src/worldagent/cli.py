"""``worldagent ...``: the command-line tool (typer).

Every command turns a ``WorldagentError`` into one red line and exit code 2, never a traceback.
"""

from __future__ import annotations

import functools
from pathlib import Path

import typer
from rich.console import Console

from worldagent.errors import WorldagentError

app = typer.Typer(
    help="Find the worlds in which trained RL agents fail or shine, and reshape what they train on.",
    no_args_is_help=True,
    add_completion=False,
)
console = Console(stderr=True)


def _print_version(value: bool) -> None:
    if value:
        from worldagent import __version__

        typer.echo(f"worldagent {__version__}")
        raise typer.Exit()


@app.callback()
def root(
    version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True, help="Print the version and exit."),
) -> None:
    """Find the worlds in which trained RL agents fail or shine, and reshape what they train on."""


def friendly_errors(command):
    """Decorator: report ``WorldagentError`` as one line on stderr and exit with code 2."""

    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        try:
            return command(*args, **kwargs)
        except WorldagentError as error:
            console.print(f"[red]error:[/red] {error}")
            raise typer.Exit(code=2) from None

    return wrapper


@app.command()
@friendly_errors
def tracks(
    n: int = typer.Option(16, "--n", help="Number of tracks to draw."),
    seed: int = typer.Option(0, "--seed", help="Track i uses seed SEED + i (CarRacing's own seeding)."),
    out: Path = typer.Option(Path("tracks.png"), "--out", help="PNG file to write."),
) -> None:
    """Generate racing tracks with CarRacing's procedural generator and draw them on one sheet."""
    from worldagent.envs.racing.render import draw_track_sheet
    from worldagent.envs.racing.tracks import generate_tracks, seeds_from

    batch = generate_tracks(seeds_from(seed, n))
    draw_track_sheet(batch, out, seeds=seeds_from(seed, n))
    console.print(f"wrote {n} tracks to {out}")


@app.command()
@friendly_errors
def drive(
    seed: int = typer.Option(0, "--seed", help="CarRacing seed of the track to drive."),
    policy: str = typer.Option("driver", "--policy", help="'driver' (scripted centreline follower) or 'random'."),
    out: Path = typer.Option(Path("episode.gif"), "--out", help="Where to draw the episode: .gif (animated) or .png."),
    key: int = typer.Option(0, "--key", help="Seed of the policy's randomness."),
) -> None:
    """Drive one Particle Racing episode on a generated track and draw it (PNG or GIF)."""
    import jax
    import numpy as np

    from worldagent.envs.core import rollout
    from worldagent.envs.racing.driver import driver_policy
    from worldagent.envs.racing.env import ParticleRacing, episode_metrics
    from worldagent.envs.racing.render import save_episode_gif, save_png, track_image
    from worldagent.envs.racing.tracks import generate_track

    policies = {"driver": None, "random": lambda k, obs, state: jax.random.randint(k, (), 0, 4)}
    if policy not in policies:
        raise WorldagentError(f"unknown policy {policy!r}; use one of: {', '.join(policies)}.")
    if out.suffix.lower() not in (".gif", ".png"):
        raise WorldagentError(f"cannot draw an episode as {out.suffix or 'a file without extension'}; use .gif or .png.")
    env = ParticleRacing()
    params = env.default_params
    world = generate_track(seed)
    act = policies[policy] or driver_policy(params)
    final, trajectory = jax.jit(lambda k: rollout(env, act, k, world, params, params.max_steps))(jax.random.key(key))
    positions = np.concatenate([np.asarray(world.centreline[:1]), np.asarray(trajectory["state"].position)[np.asarray(trajectory["alive"])]])
    crashed = bool(final.crashed)
    if out.suffix.lower() == ".gif":
        save_episode_gif(world, positions, out, crashed=crashed)
    else:
        save_png(track_image(world, 384, positions, positions[-1], crashed), out)
    metrics = {name: np.asarray(value).item() for name, value in episode_metrics(final).items()}
    console.print(
        f"return {metrics['return']:.1f}, steps {metrics['steps']}, progress {metrics['progress']:.2f}, "
        f"crashed {metrics['crashed']}, lap {metrics['lap_completed']} -> {out}"
    )
