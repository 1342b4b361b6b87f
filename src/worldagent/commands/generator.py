"""``worldagent generator train|show|report``: the world generator G(z), a VAE plus repair (paper §4.2)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from worldagent.commands.console import console, friendly_errors
from worldagent.commands.options import DATASET_CAP, PICTURE_CAP, check_counts, check_seed, env_argument
from worldagent.errors import WorldagentError
from worldagent.files import check_writable

QUALITY_FILE = "quality.json"
TRAIN_SAMPLES = 1000  # draws z ~ N(0, I) for the figures `generator train` prints


def repair_settings(texts: list[str]) -> tuple[str | None, dict]:
    """``--repair`` texts as (the repair's name or None, its settings): a bare word names the repair
    (``--repair open``), ``NAME=VALUE`` sets one of its settings, read as int, then float, else text."""
    chosen, settings = None, {}
    for text in texts:
        name, sep, value = text.partition("=")
        if not sep and name.strip() and chosen is None:
            chosen = name.strip()
            continue
        if not sep or not name.strip():
            raise WorldagentError(
                f"--repair {text!r}: name one repair (e.g. --repair open) and write settings as NAME=VALUE, e.g. --repair apples=40."
            )
        for kind in (int, float, str):
            try:
                settings[name.strip()] = kind(value.strip())
                break
            except ValueError:
                continue
    return chosen, settings


def train_generator(
    env: str, out: Path, dataset_path: Path | None, n: int, seed: int, config, repair: dict, progress: bool, repair_name: str | None = None
):
    """Train the VAE (resuming a checkpoint in ``out``), save G(z) with the repair called
    ``repair_name`` (None: the env's default); returns (the trained VAE, the repair's settings,
    defaults included, the names of those it fitted to the decoder: ``fit_repair``). The repair is
    made first: a bad name or settings cost no training."""
    from worldagent.worlds.dataset import WorldDataset, make_dataset
    from worldagent.worlds.generator import build_generator, fit_repair, make_repair, save_generator
    from worldagent.worlds.vae import train_vae

    if dataset_path is None:
        dataset_path = out / "dataset.npz"
        if not dataset_path.exists():
            make_dataset(env, n, seed, progress=progress).save(dataset_path)
    data = WorldDataset.load(dataset_path, env=env)
    repaired = make_repair(data, repair, repair_name)
    vae = train_vae(data, config, progress=progress, checkpoint_dir=out)
    generator = fit_repair(build_generator(vae, data, repair=repaired, repair_name=repair_name), data)
    save_generator(out, vae, dataset_path, generator)
    used = dict(generator.repair.config)
    return vae, used, {name for name, value in used.items() if repaired.config.get(name) != value}


def trained_epochs(directory: Path) -> int:
    """Epochs of the VAE checkpoint in ``directory`` (0 when it holds none)."""
    try:
        return len(json.loads((Path(directory) / "vae.json").read_text()).get("history", []))
    except (OSError, ValueError):
        return 0


def planned_epochs(directory: Path) -> int:
    """The epochs the VAE checkpoint in ``directory`` was started with (a killed one resumes to them; 0: none)."""
    try:
        return int(json.loads((Path(directory) / "vae.json").read_text())["config"]["epochs"])
    except (OSError, ValueError, KeyError, TypeError):
        return 0


def quality_figures(directory: Path, samples: int, seed: int, progress: bool = True) -> dict:
    """Reconstruction, and the spec-driven figures of ``worlds.quality.figures``, of a saved generator (a bar over
    its decodes with ``progress``)."""
    import jax

    from worldagent.worlds.generator import load_generator
    from worldagent.worlds.quality import assess

    if samples < 1:
        raise WorldagentError(f"--samples {samples}; draw at least 1 latent.")
    generator, vae, data = load_generator(directory)
    return assess(generator, vae, data, samples, jax.random.key(seed), progress=progress)


def key_figures(quality: dict) -> str:
    """One line of the figures that say whether search can use the generator (``quality_figures``' dict)."""
    measured, recon = quality[quality["env"]], quality["reconstruction"]
    latent, moves = measured["latent"], measured["sensitivity"]["mean_changed_world_share"]
    spreads = ", ".join(f"{name} {row['spread_ratio']:.2f}" for name, row in measured["structure"].items() if row.get("spread_ratio") is not None)
    return (
        f"KL {latent['kl_total']:.2f} nats, {latent['active_units']}/{len(latent['kl_per_dim'])} active units; "
        f"held-out NLL {recon['vae']['nll_per_world']:.1f} (mean world {recon['mean_image']['nll_per_world']:.1f}); "
        f"{measured['coverage_distinct_worlds']:,}/{measured['samples']:,} distinct decodes; a ±1 move along z changes {moves:.0%} of worlds"
        + (f"; spread under G(z) / dataset: {spreads}" if spreads else "")
        + (f"; {coverage_line(measured['coverage'])}" if measured.get("coverage") else "")
    )


def coverage_line(coverage: dict) -> str:
    """Precision, recall, density and coverage of G(z) against fresh worlds (``worlds.coverage.coverage``), beside their floor."""
    names = ("precision", "recall", "density", "coverage")
    floor = coverage.get("floor")
    return (
        f"against {coverage['worlds']:,} fresh worlds: "
        + ", ".join(f"{name} {coverage[name]:.2f}" + (f" ({floor[name]:.2f})" if floor else "") for name in names)
        + (" (fresh against fresh in brackets)" if floor else "")
    )


def coverage_table(coverage: dict) -> str:
    """Lines of each descriptor's 5/25/50/75/95% quantiles under G(z), fresh worlds and the dataset, and the
    generator parameters' spread where the env declares them."""
    from worldagent.worlds.coverage import QUANTILES

    heading = "/".join(str(q) for q in QUANTILES)
    lines = [f"quantiles {heading}%   G(z) | fresh worlds | dataset"]
    for name, sides in coverage["quantiles"].items():
        shown = " | ".join(" ".join(f"{value:.3g}" for value in sides[side]) for side in ("generator", "fresh", "dataset"))
        lines.append(f"  {name:<22} {shown}")
    params = coverage.get("generator_params")
    if params:
        rows = params["parameters"]
        lines.append(
            f"generator parameters, std under G(z) / fresh: median {params['median_std_ratio']:.2f}, lowest {params['min_std_ratio']:.2f} ("
            + ", ".join(f"{name} {row['generator_std']:.3g}/{row['fresh_std']:.3g}" for name, row in rows.items())
            + ")"
        )
    return "\n".join(lines)


def print_warnings(warnings: list[str]) -> None:
    from rich.markup import escape

    for line in warnings:
        console.print(f"[yellow]warning[/yellow]: {escape(line)}", highlight=False)


def structure_table(structure: dict) -> str:
    """Lines comparing each descriptor's mean over G(z) with the dataset's."""
    lines = ["structure (mean over worlds)   G(z)      dataset   relative difference"]
    for name, row in structure.items():
        difference = "n/a" if row["relative_difference"] is None else f"{row['relative_difference']:+.1%}"
        lines.append(f"  {name:<28} {row['generator']:<9.4g} {row['dataset']:<9.4g} {difference}")
    return "\n".join(lines)


def register(app: typer.Typer) -> None:
    """Add ``worldagent generator`` and its subcommands."""
    group = typer.Typer(help="Train, draw and assess the world generator G(z) (a VAE + repair).", no_args_is_help=True)
    app.add_typer(group, name="generator")

    @group.command("train")
    @friendly_errors
    def generator_train(
        env: str = env_argument(),
        out: Path = typer.Option(..., "--out", help="Generator directory (resumed if it holds an unfinished run)."),
        dataset_path: Path = typer.Option(None, "--dataset", help="Dataset file; default: OUT/dataset.npz, made if missing."),
        n: int = typer.Option(10_000, "--n", help=f"Worlds in a dataset made here (at most {DATASET_CAP:,})."),
        seed: int = typer.Option(0, "--seed", help="First generator seed of a dataset made here."),
        epochs: int = typer.Option(
            None,
            "--epochs",
            help="Training epochs (default: those of a VAE already trained in --out, reused as it is; else the env's paper preset, "
            "e.g. racing 25, harvest 100).",
        ),
        beta: float = typer.Option(1.0, "--beta", help="Weight of the KL term of the ELBO."),
        latent: int = typer.Option(10, "--latent", help="Latent dimensions (the paper: 10)."),
        learning_rate: float = typer.Option(1e-3, "--lr", help="Adam step size."),
        batch_size: int = typer.Option(128, "--batch-size", help="Worlds per minibatch."),
        free_bits: float = typer.Option(
            None, "--free-bits", help="Per-dimension KL floor λ, nats (Kingma et al. 2016) against collapse (default 0.5; 0: plain ELBO)."
        ),
        repair: list[str] = typer.Option(
            [],
            "--repair",
            help="The repair by name (e.g. open: new valid worlds; nearest: the paper's, dataset worlds only; `worldagent envs` lists them) "
            "and its settings NAME=VALUE, e.g. apples=40 (harvest; repeatable).",
        ),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
    ) -> None:
        """Train the VAE of G(z) on a dataset of worlds and save the generator (paper §4.2, Figure 3)."""
        from dataclasses import replace

        from worldagent.envs import registry
        from worldagent.worlds.vae import VAEConfig

        registry.get(env)  # an unknown environment fails before anything is written
        repair_name, settings = repair_settings(repair)
        registry.get(env).repair_factory(repair_name)  # an unknown repair fails before anything is written
        if epochs is None:  # a VAE already trained in --out is reused as it is (a new repair needs no training)
            epochs = planned_epochs(out) or registry.get(env).presets.get("paper", {}).get("vae_epochs", VAEConfig.epochs)
        config = VAEConfig(latent_dim=latent, beta=beta, learning_rate=learning_rate, batch_size=batch_size, epochs=epochs)
        config = config if free_bits is None else replace(config, free_bits=free_bits)
        config.validate()
        check_counts(caps={"n": DATASET_CAP}, n=n)
        check_seed(seed)
        check_writable(out, folder=True)
        epochs_before = trained_epochs(out)
        vae, used, fitted = train_generator(env, out, dataset_path, n, seed, config, settings, progress=not quiet, repair_name=repair_name)
        last = vae.kept
        repair_note = (repair_name or registry.get(env).default_repair) + "".join(
            f", {name}={value}" + ("" if name in settings else " (fitted)" if name in fitted else " (default)") for name, value in used.items()
        )
        if epochs_before >= len(vae.history):  # a finished VAE is reused as it is (a new repair costs no training)
            console.print(f"reused the VAE already trained in {out} ({epochs_before} epochs); only the repair was rebuilt (another --out retrains)")
        console.print(
            f"trained {env} generator in {out}: kept epoch {last['epoch']} of {len(vae.history)}, loss {last['train_loss']:.1f}, "
            f"held-out {last['holdout_loss']:.1f}; repair: {repair_note}"
        )
        quality = quality_figures(out, TRAIN_SAMPLES, 0, progress=not quiet)  # a quick look (~1,000 decodes); `generator report` measures more
        console.print(key_figures(quality), highlight=False)
        print_warnings(quality["warnings"])

    @group.command("show")
    @friendly_errors
    def generator_show(
        directory: Path = typer.Argument(..., help="Generator directory (from `generator train`)."),
        out: Path = typer.Option(None, "--out", help="Folder for traversals.png and reconstructions.png (default: the generator directory)."),
        count: int = typer.Option(8, "--count", help=f"Held-out worlds to reconstruct (at most {PICTURE_CAP})."),
    ) -> None:
        """Draw latent traversals of G(z) and reconstructions of held-out worlds next to their originals."""
        import numpy as np

        from worldagent.worlds.generator import load_generator
        from worldagent.worlds.pictures import reconstruction_sheet, traversal_sheet

        check_counts(caps={"count": PICTURE_CAP}, count=count)
        out = out or directory
        check_writable(out, folder=True)
        generator, vae, data = load_generator(directory)
        indices = vae.holdout_indices[:count] if len(vae.holdout_indices) else np.arange(min(count, len(data)))
        paths = [traversal_sheet(generator, out / "traversals.png"), reconstruction_sheet(generator, data, indices, out / "reconstructions.png")]
        console.print("wrote " + ", ".join(str(p) for p in paths))

    @group.command("report")
    @friendly_errors
    def generator_report(
        directory: Path = typer.Argument(..., help="Generator directory (from `generator train`)."),
        samples: int = typer.Option(10_000, "--samples", help="Draws z ~ N(0, I) for coverage / validity."),
        seed: int = typer.Option(0, "--seed", help="Seed of those draws."),
    ) -> None:
        """Measure the generator: reconstruction, self-mapping, coverage of the dataset and of fresh procedural worlds, validity and diversity."""
        import json

        from worldagent.files import write_text

        check_counts(samples=samples)
        check_seed(seed)
        check_writable(directory / QUALITY_FILE, folder=False)
        figures = quality_figures(directory, samples, seed)
        write_text(directory / QUALITY_FILE, json.dumps(figures, indent=1))
        typer.echo(json.dumps(figures, indent=1))
        typer.echo(structure_table(figures[figures["env"]]["structure"]))
        if figures[figures["env"]].get("coverage"):
            typer.echo(coverage_table(figures[figures["env"]]["coverage"]))
        console.print(key_figures(figures), highlight=False)
        print_warnings(figures["warnings"])
