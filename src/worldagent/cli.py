"""``worldagent ...``: the command-line tool (typer).

Every command turns a ``WorldagentError`` into one red line and exit code 2, never a traceback.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from worldagent.commands import register_all
from worldagent.commands.common import AGENT_HELP, ENV_HELP, campaign, console, friendly_errors
from worldagent.errors import WorldagentError

app = typer.Typer(
    help="Find the worlds in which trained RL agents fail or shine, and reshape what they train on.",
    no_args_is_help=True,
    add_completion=False,
)


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
    from worldagent.envs.racing.render import save_episode_gif, track_image
    from worldagent.envs.racing.tracks import generate_track
    from worldagent.files import save_png

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


@app.command()
@friendly_errors
def maps(
    n: int = typer.Option(16, "--n", help="Number of Resource Harvest maps to draw."),
    seed: int = typer.Option(0, "--seed", help="Map i uses seed SEED + i."),
    out: Path = typer.Option(Path("maps.png"), "--out", help="PNG file to write."),
) -> None:
    """Generate Resource Harvest maps (corner regions, walls, apple clusters) and draw them on one sheet."""
    from worldagent.envs.harvest.maps import generate_maps, seeds_from
    from worldagent.envs.harvest.render import draw_map_sheet

    if n < 1:
        raise WorldagentError(f"--n is {n}; ask for at least one map.")
    draw_map_sheet(generate_maps(seeds_from(seed, n)), out)
    console.print(f"wrote {n} maps to {out}")


@app.command()
@friendly_errors
def dataset(
    env: str = typer.Argument(..., help=ENV_HELP),
    n: int = typer.Option(10_000, "--n", help="Number of worlds (the paper: 10,000)."),
    seed: int = typer.Option(0, "--seed", help="World i uses generator seed SEED + i."),
    out: Path = typer.Option(..., "--out", help="Dataset file to write (.npz)."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Generate a dataset of worlds with the environment's procedural generator (paper §5.2.1)."""
    from worldagent.worlds.dataset import make_dataset

    data = make_dataset(env, n, seed, progress=not quiet)
    data.save(out)
    console.print(f"wrote {len(data):,} {env} worlds to {out} (fingerprint {data.fingerprint})")


generator_app = typer.Typer(help="Train, draw and assess the world generator G(z) (a VAE + repair).", no_args_is_help=True)
app.add_typer(generator_app, name="generator")


@generator_app.command("train")
@friendly_errors
def generator_train(
    env: str = typer.Argument(..., help=ENV_HELP),
    out: Path = typer.Option(..., "--out", help="Generator directory (resumed if it holds an unfinished run)."),
    dataset_path: Path = typer.Option(None, "--dataset", help="Dataset file; default: OUT/dataset.npz, made if missing."),
    n: int = typer.Option(10_000, "--n", help="Worlds in a dataset made here."),
    seed: int = typer.Option(0, "--seed", help="First generator seed of a dataset made here."),
    epochs: int = typer.Option(25, "--epochs", help="Training epochs."),
    beta: float = typer.Option(1.0, "--beta", help="Weight of the KL term of the ELBO."),
    latent: int = typer.Option(10, "--latent", help="Latent dimensions (the paper: 10)."),
    learning_rate: float = typer.Option(1e-3, "--lr", help="Adam step size."),
    batch_size: int = typer.Option(128, "--batch-size", help="Worlds per minibatch."),
    apples: int = typer.Option(None, "--apples", help="Harvest: apples per generated map (default: the dataset's median)."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
) -> None:
    """Train the VAE of G(z) on a dataset of worlds and save the generator (paper §4.2, Figure 3)."""
    from worldagent.worlds.dataset import WorldDataset, make_dataset
    from worldagent.worlds.generator import build_generator, save_generator
    from worldagent.worlds.kinds import world_kind
    from worldagent.worlds.vae import VAEConfig, train_vae

    world_kind(env)
    config = VAEConfig(latent_dim=latent, beta=beta, learning_rate=learning_rate, batch_size=batch_size, epochs=epochs)
    config.validate()
    if dataset_path is None:
        dataset_path = out / "dataset.npz"
        if not dataset_path.exists():
            make_dataset(env, n, seed, progress=not quiet).save(dataset_path)
    data = WorldDataset.load(dataset_path, env=env)
    vae = train_vae(data, config, progress=not quiet, checkpoint_dir=out)
    save_generator(out, vae, dataset_path, build_generator(vae, data, apples))
    last = vae.history[-1]
    console.print(f"trained {env} generator in {out}: loss {last['train_loss']:.1f}, held-out {last['holdout_loss']:.1f}")


@generator_app.command("show")
@friendly_errors
def generator_show(
    directory: Path = typer.Argument(..., help="Generator directory (from `generator train`)."),
    out: Path = typer.Option(None, "--out", help="Folder for traversals.png and reconstructions.png (default: the generator directory)."),
    count: int = typer.Option(8, "--count", help="Held-out worlds to reconstruct."),
) -> None:
    """Draw latent traversals of G(z) and reconstructions of held-out worlds next to their originals."""
    from worldagent.worlds.generator import load_generator
    from worldagent.worlds.pictures import reconstruction_sheet, traversal_sheet

    generator, vae, data = load_generator(directory)
    out = out or directory
    indices = vae.holdout_indices[:count] if len(vae.holdout_indices) else np.arange(min(count, len(data)))
    paths = [traversal_sheet(generator, out / "traversals.png"), reconstruction_sheet(generator, data, indices, out / "reconstructions.png")]
    console.print("wrote " + ", ".join(str(p) for p in paths))


@generator_app.command("report")
@friendly_errors
def generator_report(
    directory: Path = typer.Argument(..., help="Generator directory (from `generator train`)."),
    samples: int = typer.Option(10_000, "--samples", help="Draws z ~ N(0, I) for coverage / validity."),
    seed: int = typer.Option(0, "--seed", help="Seed of those draws."),
) -> None:
    """Measure the generator: reconstruction, self-mapping and coverage (racing), validity (harvest)."""
    import json

    import jax

    from worldagent.files import write_text
    from worldagent.worlds.generator import load_generator
    from worldagent.worlds.quality import harvest_figures, racing_figures, reconstruction
    from worldagent.worlds.vae import split_holdout

    if samples < 1:
        raise WorldagentError(f"--samples {samples}; draw at least 1 latent.")
    generator, vae, data = load_generator(directory)
    train, held = split_holdout(len(data), vae.config.holdout, vae.config.seed)
    figures = {"env": data.env, "worlds": len(data), "reconstruction": reconstruction(generator, data, held, train)}
    key = jax.random.key(seed)
    figures[data.env] = racing_figures(generator, data, samples, key) if data.env == "racing" else harvest_figures(generator, samples, key)
    figures["training"] = {"epochs": len(vae.history), "final": vae.history[-1]}
    write_text(directory / "quality.json", json.dumps(figures, indent=1))
    typer.echo(json.dumps(figures, indent=1))


@app.command()
@friendly_errors
def search(
    env: str = typer.Argument(..., help=ENV_HELP),
    agent: str = typer.Option(..., "--agent", help=AGENT_HELP),
    generator: Path = typer.Option(..., "--generator", help="Generator directory (from `worldagent generator train`)."),
    objective: str = typer.Option(
        "reward",
        "--objective",
        help="Metric: reward, or racing return|normalised_return|crashed|lap_completed|progress|steps, harvest group_reward|conflict|equality|sustainability|peace.",
    ),
    minimize: bool = typer.Option(False, "--minimize/--maximize", help="Direction of the search."),
    optimiser: str = typer.Option("cmaes", "--optimiser", help="cmaes, bo or random."),
    budget: int = typer.Option(2000, "--budget", help="Worlds to evaluate (rounded up to whole CMA-ES generations)."),
    repeats: int = typer.Option(8, "--repeats", help="Episodes per world (the paper: 8)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the optimiser and of every episode."),
    out: Path = typer.Option(Path("runs/search"), "--out", help="Run directory; its store.sqlite may hold many campaigns."),
    name: str = typer.Option(None, "--name", help="Campaign name (default: optimiser-direction-objective-seed)."),
    resume: bool = typer.Option(False, "--resume", help="Continue a killed campaign of the same name."),
    tagger: list[int] = typer.Option([], "--tagger", help="Harvest: an agent allowed to TAG (repeatable)."),
    greedy: bool = typer.Option(False, "--greedy", help="Trained actor-critics act by argmax instead of sampling."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Search the generator's latent space for worlds that minimise or maximise an agent metric (paper §4.4)."""
    from worldagent.search.objectives import metric_name

    direction = "min" if minimize else "max"
    name = name or f"{optimiser}-{direction}-{metric_name(env, objective)}-s{seed}"
    evaluations, spec = campaign(
        env, agent, generator, objective, not minimize, optimiser, budget, repeats, seed, out, name, resume, tagger, greedy, quiet
    )
    scores = np.array([e.score for e in evaluations])
    best = evaluations[int(np.nanargmin(scores) if minimize else np.nanargmax(scores))]
    console.print(
        f"{name}: {len(evaluations)} worlds; {spec.objective} mean {np.nanmean(scores):.4g}; {direction} {best.score:.4g} "
        f"(generation {best.generation}, slot {best.slot}) -> {out / 'store.sqlite'}"
    )


evaluate_app = typer.Typer(help="Evaluate agents on worlds from the generator.", no_args_is_help=True)
app.add_typer(evaluate_app, name="evaluate")


@evaluate_app.command("random")
@friendly_errors
def evaluate_random(
    env: str = typer.Argument(..., help=ENV_HELP),
    agent: str = typer.Option(..., "--agent", help=AGENT_HELP),
    generator: Path = typer.Option(..., "--generator", help="Generator directory (from `worldagent generator train`)."),
    worlds: int = typer.Option(1000, "--worlds", help="Worlds z ~ N(0, I) to evaluate (the paper: 1,000)."),
    metric: str = typer.Option("reward", "--metric", help="Metric whose distribution to draw (see `search --help`)."),
    repeats: int = typer.Option(8, "--repeats", help="Episodes per world (the paper: 8)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the latents and episodes."),
    out: Path = typer.Option(Path("runs/evaluate"), "--out", help="Run directory (store.sqlite and the histogram)."),
    resume: bool = typer.Option(False, "--resume", help="Continue a killed evaluation."),
    tagger: list[int] = typer.Option([], "--tagger", help="Harvest: an agent allowed to TAG (repeatable)."),
    greedy: bool = typer.Option(False, "--greedy", help="Trained actor-critics act by argmax instead of sampling."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """The distribution of a metric over randomly generated worlds (paper §6.1.1, Figure 6a)."""
    from worldagent.reports.figures import distribution_figure
    from worldagent.search.objectives import metric_name
    from worldagent.search.optimisers import OptimiserConfig

    config = OptimiserConfig(random_batch=min(max(worlds, 1), 250))
    name = f"random-{metric_name(env, metric)}-s{seed}"
    evaluations, spec = campaign(
        env, agent, generator, metric, True, "random", worlds, repeats, seed, out, name, resume, tagger, greedy, quiet, config
    )
    scores = np.array([e.score for e in evaluations])
    figure = distribution_figure(
        {"random worlds": scores}, spec.objective, out / f"{name}.png", f"{env}: {spec.objective} over {len(scores)} random worlds"
    )
    line = f"{name}: {len(scores)} worlds x {repeats} episodes; {spec.objective} mean {np.nanmean(scores):.4g} (sd {np.nanstd(scores):.3g})"
    if env == "racing" and spec.objective == "return":
        normalised = np.array([np.mean([e["normalised_return"] for e in ev.episodes]) for ev in evaluations])
        line += f", normalised {normalised.mean():.3f}"
    console.print(f"{line} -> {figure}")


ALGORITHMS = {"racing": ("acktr", "ppo"), "harvest": ("dqn",)}


@app.command()
@friendly_errors
def train(
    env: str = typer.Argument(..., help=ENV_HELP),
    out: Path = typer.Option(..., "--out", help="Run directory: checkpoint, learning curve (CSV, PNG), the saved agent."),
    algo: str = typer.Option(None, "--algo", help="racing: acktr (the paper's) or ppo; harvest: dqn (independent DQNs)."),
    episodes: int = typer.Option(None, "--episodes", help="Training episodes (default: the paper's budget, racing 10,000, harvest 5,000)."),
    worlds: str = typer.Option(
        "generator", "--worlds", help="Training worlds: generator (procedural), vae (G(z), needs --generator), or a dataset .npz."
    ),
    generator: Path = typer.Option(None, "--generator", help="Generator directory for --worlds vae."),
    tagger: list[int] = typer.Option([], "--tagger", help="Harvest: the agent allowed to TAG (the paper's influencing experiment: 0)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the run."),
    resume: bool = typer.Option(True, "--resume/--restart", help="Continue from the run directory's checkpoint, or start over."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Train agents on a distribution of worlds (paper §4.3, §5.3); a killed run resumes."""
    from worldagent.agents.distributions import world_distribution

    if env not in ALGORITHMS:
        raise WorldagentError(f"unknown environment {env!r}; use racing or harvest.")
    algo = algo or ALGORITHMS[env][0]
    if algo not in ALGORITHMS[env]:
        raise WorldagentError(f"unknown algorithm {algo!r} for {env}; use one of: {', '.join(ALGORITHMS[env])}.")
    if episodes is not None and episodes < 1:
        raise WorldagentError(f"--episodes {episodes}; train for at least one episode.")
    if worlds == "vae" and generator is None:
        raise WorldagentError("--worlds vae draws G(z): pass --generator DIR (from `worldagent generator train`).")
    distribution = world_distribution(env, worlds, generator_dir=generator, progress=not quiet)
    if env == "racing":
        from worldagent.agents.acktr import ACKTRConfig
        from worldagent.agents.ppo import PPOConfig
        from worldagent.agents.training import train_racing

        if tagger:
            raise WorldagentError("--tagger applies to harvest only.")
        config_class = {"acktr": ACKTRConfig, "ppo": PPOConfig}[algo]
        config = config_class() if episodes is None else config_class(total_episodes=episodes)
        result = train_racing(config, distribution, out, algo, seed=seed, progress=not quiet, resume=resume, distribution_spec=worlds)
        console.print(f"trained {algo} for {result.episodes:,} episodes ({result.env_steps:,} steps, {result.wall_seconds:.0f} s) -> {out}")
        return
    from worldagent.agents.dqn import DQNConfig
    from worldagent.agents.dqn_run import train_harvest

    if len(tagger) > 1:
        raise WorldagentError("--tagger: the influencing experiment gives one agent the TAG action; pass one index.")
    config = DQNConfig(num_episodes=episodes or DQNConfig.num_episodes, tagger=tagger[0] if tagger else None, seed=seed)
    result = train_harvest(config, distribution, out, progress=not quiet, resume=resume)
    console.print(f"trained 4 DQNs for {config.num_chunks * config.num_envs:,} episodes ({result.env_steps:,} steps, {result.wall_s:.0f} s) -> {out}")


register_all(app)  # the commands defined in worldagent/commands/*.py
