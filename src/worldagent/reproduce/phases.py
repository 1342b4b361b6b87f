"""The phases of the paper's pipeline for one environment (paper §4–§6), one function each.

Each phase is ``phase(ctx) -> outputs``: it reads what earlier phases left in the
environment's directory, writes its own results there, and returns a small JSON-able dict
(paths relative to the run directory, a few numbers and a one-line ``summary``) for the
manifest. Phases rely on their layer's own resume: the VAE and the agents restart from their
checkpoints, campaigns from the run store, the influence experiment from its cache, so a
phase interrupted half-way loses little when it runs again.

Layout of ``<run>/<env>/``::

    dataset.npz            the procedurally generated worlds (paper §5.2.1)
    generator/             the VAE and G(z) (quality.json: its quality figures)
    agent/                 the training run (checkpoint, curve.csv/png, the saved agent)
    store.sqlite           random / strategic (min, max) / comparison campaigns
    influence/             the influencing experiment (influence.json, its agents)
    figures/               figures drawn by phases that roll agents out
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from worldagent.errors import WorldagentError
from worldagent.files import write_text
from worldagent.reproduce.presets import TAGGER, Preset

QUALITY_SAMPLES = 1000  # draws z ~ N(0, I) for the generator's coverage / validity figures


def reward_metric(env: str) -> str:
    """The paper's main metric of ``env`` (racing return, harvest group reward; §4.4)."""
    from worldagent.search.objectives import metric_name

    return metric_name(env, "reward")


def campaign_names(env: str, seed: int) -> dict[str, str]:
    """Store names of the random and strategic campaigns (those of ``search.experiments``)."""
    metric = reward_metric(env)
    return {"random": f"random-{metric}-s{seed}", "min": f"cmaes-min-{metric}-s{seed}", "max": f"cmaes-max-{metric}-s{seed}"}


def compare_names(env: str, seeds, optimisers=("cmaes", "bo", "random")) -> dict[str, list[str]]:
    """Store names of the comparison campaigns, by optimiser (``search.experiments.compare_optimisers``)."""
    metric = reward_metric(env)
    return {opt: [f"compare-{opt}-min-{metric}-s{seed}" for seed in seeds] for opt in optimisers}


@dataclass
class EnvContext:
    """What a phase of one environment needs; the generator and agent are loaded once, on demand.

    Attributes:
        run_dir: the run directory.
        env: "racing" or "harvest".
        preset: the run's preset.
        progress: show progress bars.
    """

    run_dir: Path
    env: str
    preset: Preset
    progress: bool = True
    _cache: dict = field(default_factory=dict, repr=False)

    @property
    def dir(self) -> Path:
        return self.run_dir / self.env

    @property
    def budgets(self):
        return self.preset.budgets(self.env)

    @property
    def seed(self) -> int:
        return self.preset.seed

    @property
    def dataset_path(self) -> Path:
        return self.dir / "dataset.npz"

    @property
    def generator_dir(self) -> Path:
        return self.dir / "generator"

    @property
    def agent_dir(self) -> Path:
        return self.dir / "agent"

    @property
    def store_path(self) -> Path:
        return self.dir / "store.sqlite"

    @property
    def figures(self) -> Path:
        return self.dir / "figures"

    def rel(self, path: Path) -> str:
        """``path`` relative to the run directory (the run directory may be moved)."""
        return str(Path(path).relative_to(self.run_dir))

    def cached(self, name: str, make: Callable[[], Any]) -> Any:
        if name not in self._cache:
            self._cache[name] = make()
        return self._cache[name]

    def generator(self):
        """G(z) from this run's generator directory and dataset."""
        from worldagent.worlds.generator import load_generator

        return self.cached("generator", lambda: load_generator(self.generator_dir, self.dataset_path)[0])

    def policy(self):
        """The trained agent(s) of the agent phase."""
        from worldagent.agents.policy import load_policy

        where = self.agent_dir / ("policy" if self.env == "racing" else "agents")
        return self.cached("policy", lambda: load_policy(where, env=self.env).policy)

    def env_and_params(self):
        """The env object and its params (harvest: agent 0 may TAG, §6.2.2)."""
        from worldagent.commands.common import env_and_params

        return self.cached("env", lambda: env_and_params(self.env, [TAGGER] if self.env == "harvest" else []))

    def store(self):
        from worldagent.store import RunStore

        return RunStore(self.store_path)


# -- phase 1: worlds and the generator (paper §4.2, §5.2.1) ---------------------------------------


def dataset_phase(ctx: EnvContext) -> dict:
    """The procedurally generated dataset the VAE learns (10,000 worlds in the paper)."""
    from worldagent.worlds.dataset import make_dataset

    data = make_dataset(ctx.env, ctx.budgets.worlds, ctx.seed, progress=ctx.progress)
    data.save(ctx.dataset_path)
    return {
        "dataset": ctx.rel(ctx.dataset_path),
        "worlds": len(data),
        "fingerprint": data.fingerprint,
        "summary": f"{len(data):,} worlds (fingerprint {data.fingerprint})",
    }


def vae_config(preset: Preset, env: str):
    """The VAE settings of ``preset`` (the paper's architecture at the ``paper`` preset)."""
    from worldagent.worlds.vae import VAEConfig

    hidden = tuple(preset.vae_hidden)
    return VAEConfig(encoder=hidden, decoder=hidden[::-1], batch_size=preset.vae_batch_size, epochs=preset.budgets(env).vae_epochs, seed=preset.seed)


def generator_phase(ctx: EnvContext) -> dict:
    """Train the VAE (resuming its checkpoint), save G(z), measure it and draw its traversals."""
    import jax

    from worldagent.worlds.dataset import WorldDataset
    from worldagent.worlds.generator import build_generator, save_generator
    from worldagent.worlds.pictures import traversal_sheet
    from worldagent.worlds.quality import harvest_figures, racing_figures, reconstruction
    from worldagent.worlds.vae import split_holdout, train_vae

    data = WorldDataset.load(ctx.dataset_path, env=ctx.env)
    config = vae_config(ctx.preset, ctx.env)
    vae = train_vae(data, config, progress=ctx.progress, checkpoint_dir=ctx.generator_dir)
    generator = build_generator(vae, data)
    save_generator(ctx.generator_dir, vae, ctx.dataset_path, generator)
    train, held = split_holdout(len(data), config.holdout, config.seed)
    key = jax.random.key(ctx.seed)
    quality = {
        "env": ctx.env,
        "worlds": len(data),
        "reconstruction": reconstruction(generator, data, held, train),
        ctx.env: (racing_figures(generator, data, QUALITY_SAMPLES, key) if ctx.env == "racing" else harvest_figures(generator, QUALITY_SAMPLES, key)),
        "training": {"epochs": len(vae.history), "final": vae.history[-1], "history": vae.history},
    }
    quality_path = write_text(ctx.generator_dir / "quality.json", json.dumps(quality, indent=1))
    traversals = traversal_sheet(generator, ctx.figures / "generator_traversals.png")
    accuracy = quality["reconstruction"]["vae"]["accuracy"]
    return {
        "generator": ctx.rel(ctx.generator_dir),
        "quality": ctx.rel(quality_path),
        "traversals": ctx.rel(traversals),
        "final_loss": vae.history[-1]["holdout_loss"],
        "summary": f"{len(vae.history)} epochs, held-out loss {vae.history[-1]['holdout_loss']:.1f}, cell accuracy {accuracy:.3f}",
    }


# -- phase 2: agents (paper §4.3, §5.3) -----------------------------------------------------------


def racing_train_config(preset: Preset):
    """The racing algorithm's config at the preset's budget."""
    from worldagent.agents.acktr import ACKTRConfig
    from worldagent.agents.ppo import PPOConfig

    budgets = preset.budgets("racing")
    overrides = {"total_episodes": budgets.episodes, **({"num_envs": budgets.train_envs} if budgets.train_envs else {})}
    return {"acktr": ACKTRConfig, "ppo": PPOConfig}[preset.racing_algo](**overrides)


def harvest_train_config(preset: Preset):
    """The independent-DQN config at the preset's budget, agent 0 the tagger (§6.2.2)."""
    from worldagent.agents.dqn import DQNConfig

    budgets = preset.budgets("harvest")
    overrides = {
        **({"num_envs": budgets.train_envs} if budgets.train_envs else {}),
        **({"learning_starts": budgets.learning_starts} if budgets.learning_starts is not None else {}),
    }
    return DQNConfig(num_episodes=budgets.episodes, tagger=TAGGER, seed=preset.seed, **overrides)


def agent_phase(ctx: EnvContext) -> dict:
    """Train the agents on the procedural worlds of the dataset (resuming their checkpoint)."""
    from worldagent.agents.distributions import world_distribution

    distribution = world_distribution(ctx.env, str(ctx.dataset_path))
    if ctx.env == "racing":
        import worldagent.agents.acktr  # noqa: F401  (registers ACKTR with the trainer)
        from worldagent.agents.training import train_racing

        result = train_racing(
            racing_train_config(ctx.preset),
            distribution,
            ctx.agent_dir,
            ctx.preset.racing_algo,
            seed=ctx.seed,
            progress=ctx.progress,
            resume=True,
            distribution_spec=ctx.rel(ctx.dataset_path),
        )
        last = {k: float(v[-1]) for k, v in result.curve.items() if len(v)}
        return {
            "agent": ctx.rel(ctx.agent_dir / "policy"),
            "curve": ctx.rel(ctx.agent_dir / "curve.png"),
            "algo": ctx.preset.racing_algo,
            "episodes": result.episodes,
            "env_steps": result.env_steps,
            "train_s": round(result.wall_seconds, 2),
            "final": last,
            "summary": f"{ctx.preset.racing_algo} {result.episodes:,} episodes; last update: return {last.get('return', float('nan')):.1f}, "
            f"crash rate {last.get('crashed', float('nan')):.2f}",
        }
    from worldagent.agents.dqn_run import train_harvest

    config = harvest_train_config(ctx.preset)
    result = train_harvest(config, distribution, ctx.agent_dir, progress=ctx.progress, resume=True)
    last = result.history[-1] if result.history else {}
    episodes = config.num_chunks * config.num_envs
    return {
        "agent": ctx.rel(ctx.agent_dir / "agents"),
        "curve": ctx.rel(ctx.agent_dir / "curve.png"),
        "algo": "dqn",
        "tagger": TAGGER,
        "episodes": episodes,
        "env_steps": result.env_steps,
        "train_s": round(result.wall_s, 2),
        "final": {k: last[k] for k in ("group_reward", "equality", "conflict") if k in last},
        "summary": f"4 DQNs, {episodes:,} episodes; last chunk: group reward {last.get('group_reward', float('nan')):.1f}, "
        f"conflict {last.get('conflict', float('nan')):.2f}",
    }


# -- phase 3: optimising worlds (paper §4.4, §6.1) ------------------------------------------------


def random_phase(ctx: EnvContext) -> dict:
    """Evaluate the agents on random worlds z ~ N(0, I) (paper §6.1.1, Figure 6a)."""
    from worldagent.search.experiments import random_evaluation

    metric = reward_metric(ctx.env)
    env, params = ctx.env_and_params()
    with ctx.store() as store:
        evaluations = random_evaluation(
            store,
            ctx.env,
            env,
            ctx.policy(),
            ctx.generator(),
            params,
            metric,
            worlds=ctx.budgets.random_worlds,
            repeats=ctx.preset.repeats,
            seed=ctx.seed,
            progress=ctx.progress,
            resume=True,
        )
    scores = np.array([e.score for e in evaluations])
    return {
        "store": ctx.rel(ctx.store_path),
        "campaign": campaign_names(ctx.env, ctx.seed)["random"],
        "worlds": len(scores),
        "mean": float(np.nanmean(scores)),
        "summary": f"{len(scores):,} worlds x {ctx.preset.repeats} episodes; mean {metric} {np.nanmean(scores):.4g} (sd {np.nanstd(scores):.3g})",
    }


def random_scores(ctx: EnvContext) -> np.ndarray:
    """Per-world scores of the random evaluation (the baseline of Figures 6b and 7)."""
    with ctx.store() as store:
        return np.array([e.score for e in store.evaluations(campaign_names(ctx.env, ctx.seed)["random"])])


def strategic_phase(ctx: EnvContext) -> dict:
    """CMA-ES searches for the worlds that minimise and maximise reward (§6.1.2, Figures 1, 6b)."""
    from worldagent.reports.strategic import strategic_figure
    from worldagent.search.experiments import strategic_evaluation

    metric = reward_metric(ctx.env)
    env, params = ctx.env_and_params()
    policy = ctx.policy()
    with ctx.store() as store:
        result = strategic_evaluation(
            store,
            ctx.env,
            env,
            policy,
            ctx.generator(),
            params,
            metric,
            budget=ctx.budgets.strategic_budget,
            repeats=ctx.preset.repeats,
            seed=ctx.seed,
            optimiser="cmaes",
            progress=ctx.progress,
            resume=True,
        )
    low, high = result["min"], result["max"]
    figure = strategic_figure(
        ctx.env, env, policy, params, low, high, random_scores(ctx), metric, ctx.figures / "strategic.png", key=result.get("keys")
    )
    return {
        "store": ctx.rel(ctx.store_path),
        "campaigns": list(result["campaigns"]),
        "min": float(low.score),
        "max": float(high.score),
        "figure": ctx.rel(figure),
        "summary": f"{metric}: min {low.score:.4g}, max {high.score:.4g} ({ctx.budgets.strategic_budget} worlds each)",
    }


def compare_phase(ctx: EnvContext) -> dict:
    """ES against BO against random search, all minimising reward (§6.1.3, Figure 7)."""
    budgets = ctx.budgets
    if budgets.compare_budget < 1:
        return {"skipped": "the preset's compare_budget is 0", "summary": "skipped (compare_budget 0)"}
    from worldagent.reports.comparison import comparison_figure
    from worldagent.search.experiments import compare_optimisers

    metric = reward_metric(ctx.env)
    env, params = ctx.env_and_params()
    runs = {}
    with ctx.store() as store:
        for optimisers, budget in (
            (("cmaes",), budgets.compare_budget),
            (("bo",), budgets.bo_budget or budgets.compare_budget),
            (("random",), budgets.compare_budget),
        ):
            runs.update(
                compare_optimisers(
                    store,
                    ctx.env,
                    env,
                    ctx.policy(),
                    ctx.generator(),
                    params,
                    metric,
                    maximize=False,
                    optimisers=optimisers,
                    budget=budget,
                    seeds=tuple(budgets.compare_seeds),
                    repeats=ctx.preset.repeats,
                    progress=ctx.progress,
                    resume=True,
                )
            )
    figure = comparison_figure(runs, random_scores(ctx), metric, ctx.figures / "comparison.png", maximize=False)
    best = {opt: float(np.nanmin(np.concatenate([np.ravel(r) for r in scores]))) for opt, scores in runs.items()}
    return {
        "store": ctx.rel(ctx.store_path),
        "campaigns": compare_names(ctx.env, budgets.compare_seeds, tuple(runs)),
        "best": best,
        "figure": ctx.rel(figure),
        "summary": "lowest " + ", ".join(f"{opt} {value:.4g}" for opt, value in best.items()),
    }


# -- influencing (paper §6.2) --------------------------------------------------------------------


def influence_phase(ctx: EnvContext) -> dict:
    """Retrain agents on worlds with a desired property and compare them with default training (§6.2, Figure 8)."""
    from worldagent.influence.experiment import example_indices, influence, load_influenced_worlds
    from worldagent.influence.selection import parse_selection
    from worldagent.reports.influence import influence_figure

    budgets = ctx.budgets
    env, params = ctx.env_and_params()
    racing = ctx.env == "racing"
    out = ctx.dir / "influence"
    result = influence(
        out,
        ctx.env,
        ctx.policy(),
        ctx.generator(),
        params,
        parse_selection(ctx.preset.selection(ctx.env), ctx.env),
        algo=ctx.preset.algo(ctx.env),
        episodes=budgets.influence_episodes,
        seeds=tuple(budgets.influence_seeds),
        candidates=budgets.influence_candidates,
        search_budget=budgets.influence_search_budget,
        eval_worlds=budgets.influence_eval_worlds,
        repeats=ctx.preset.repeats,
        tagger=None if racing else TAGGER,
        progress=ctx.progress,
        config=racing_train_config(ctx.preset) if racing else harvest_train_config(ctx.preset),
        env=env,
        seed=ctx.seed,
    )
    worlds, _, values = load_influenced_worlds(out, ctx.env)
    examples = take_worlds(worlds, example_indices(values, 4))
    figure = influence_figure(result, examples, ctx.env, ctx.figures / "influence.png")
    return {
        "influence": ctx.rel(out / "influence.json"),
        "figure": ctx.rel(figure),
        "selection": ctx.preset.selection(ctx.env),
        "selected": result["worlds"]["selected"],
        "summary": influence_summary(result),
    }


def take_worlds(worlds, indices):
    """The worlds at ``indices`` of a batched world pytree (still batched)."""
    import jax

    return jax.tree_util.tree_map(lambda leaf: np.asarray(leaf)[np.asarray(indices)], worlds)


def influence_summary(result: dict) -> str:
    """One line: how many worlds were selected, and each compared metric, default -> influenced."""
    summary = result.get("summary", {})
    parts = [f"{result.get('worlds', {}).get('selected', '?')} worlds selected"]
    for metric, by_label in summary.items():
        parts.append(f"{metric} {by_label['default']['mean']:.3g} -> {by_label['influenced']['mean']:.3g}")
    return "; ".join(parts)


PHASE_FUNCTIONS: dict[str, Callable[[EnvContext], dict]] = {
    "dataset": dataset_phase,
    "generator": generator_phase,
    "agent": agent_phase,
    "random": random_phase,
    "strategic": strategic_phase,
    "compare": compare_phase,
    "influence": influence_phase,
}

# What each phase is computed from: restarting a phase restarts everything that depends on it.
DEPENDS = {
    "dataset": (),
    "generator": ("dataset",),
    "agent": ("dataset",),
    "random": ("generator", "agent"),
    "strategic": ("random",),
    "compare": ("random",),
    "influence": ("generator", "agent"),
}


def dependents(phase: str) -> list[str]:
    """``phase`` and every phase computed (directly or not) from it, in pipeline order."""
    if phase not in DEPENDS:
        raise WorldagentError(f"unknown phase {phase!r}; use one of: {', '.join(DEPENDS)}.")
    found = {phase}
    changed = True
    while changed:
        changed = False
        for name, parents in DEPENDS.items():
            if name not in found and found.intersection(parents):
                found.add(name)
                changed = True
    return [name for name in DEPENDS if name in found]
