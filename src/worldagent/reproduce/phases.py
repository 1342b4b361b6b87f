"""The phases of the paper's pipeline for one environment (paper §4–§6), one function each.

Each phase is ``phase(ctx) -> outputs``: it reads what earlier phases left in the
environment's directory (``layout.RunLayout``), writes its own results there, and returns a
small JSON-able dict (paths relative to the run directory, a few numbers and a one-line
``summary``) for the manifest. The experiments themselves are calls into
``worldagent.experiments``; a phase only chooses the preset's budgets and draws the figures.
Phases rely on their layer's own resume: the VAE and the agents restart from their
checkpoints, campaigns from the run store, the influence experiment from its cache, so a
phase interrupted half-way loses little when it runs again.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.files import write_text
from worldagent.reproduce.layout import RunLayout
from worldagent.reproduce.presets import Preset
from worldagent.search.optimisers import OPTIMISERS

QUALITY_SAMPLES = 1000  # draws z ~ N(0, I) for the generator's coverage / validity figures


@dataclass
class EnvContext:
    """What a phase of one environment needs; the generator and agent are loaded once, on demand.

    Attributes:
        run_dir: the run directory.
        env: the registered environment's name.
        preset: the run's preset.
        progress: show progress bars.
    """

    run_dir: Path
    env: str
    preset: Preset
    progress: bool = True
    _cache: dict = field(default_factory=dict, repr=False)

    @property
    def layout(self) -> RunLayout:
        return RunLayout(Path(self.run_dir), self.env)

    @property
    def spec(self):
        return registry.get(self.env)

    @property
    def budgets(self):
        return self.preset.budgets(self.env)

    @property
    def seed(self) -> int:
        return self.preset.seed

    @property
    def metric(self) -> str:
        """The paper's main metric of the env (racing return, harvest group reward; §4.4)."""
        return self.spec.metrics.main

    @property
    def algo(self) -> str:
        return self.preset.algo_of(self.env)

    @property
    def options(self) -> dict:
        """The env options of this run's agents (``Preset.options_of``)."""
        return self.preset.options_of(self.env)

    def cached(self, name: str, make: Callable[[], Any]) -> Any:
        if name not in self._cache:
            self._cache[name] = make()
        return self._cache[name]

    def setup(self):
        """``experiments.Setup``: the trained agents on this run's G(z), with the reproduce options."""
        from worldagent import experiments
        from worldagent.worlds.generator import load_generator

        def make():
            generator = load_generator(self.layout.generator_dir, self.layout.dataset_path)[0]
            options = self.options
            return experiments.setup(self.env, str(self.layout.agent_dir), generator, options=options, repeats=self.preset.repeats)

        return self.cached("setup", make)

    def train_config(self, episodes: int):
        """The env's algorithm's config at ``episodes``, with the preset's parallel envs / warm-up and ``--set``'s fields."""
        from worldagent.agents.algorithms import training_config

        b = self.budgets
        overrides = {
            **({"num_envs": b.train_envs} if b.train_envs else {}),
            **({"learning_starts": b.learning_starts} if b.learning_starts is not None else {}),
            **self.preset.settings_of(self.env),
        }
        return training_config(self.spec, self.algo, episodes=episodes, options=self.options, **overrides)

    def store(self):
        from worldagent.store import RunStore

        return RunStore(self.layout.store_path)


# -- phase 1: worlds and the generator (paper §4.2, §5.2.1) ---------------------------------------


def dataset_phase(ctx: EnvContext) -> dict:
    """The procedurally generated dataset the VAE learns (10,000 worlds in the paper)."""
    from worldagent.worlds.dataset import make_dataset

    data = make_dataset(ctx.env, ctx.budgets.worlds, ctx.seed, progress=ctx.progress)
    data.save(ctx.layout.dataset_path)
    return {
        "dataset": ctx.layout.rel(ctx.layout.dataset_path),
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
    """Train the VAE (resuming its checkpoint), save G(z), measure it and draw its traversals.

    A generator its quality gate rejects (``worlds.quality.gate``) is refused in one line, its
    figures written first, unless the preset accepts it for a reason (``Preset.accept_generator``);
    the verdict is recorded as ``gate`` in quality.json and in the phase's outputs.
    """
    import jax

    from worldagent.worlds.dataset import WorldDataset
    from worldagent.worlds.generator import build_generator, fit_repair, save_generator
    from worldagent.worlds.pictures import traversal_sheet
    from worldagent.worlds.quality import assess, gate_kinds
    from worldagent.worlds.vae import train_vae

    layout = ctx.layout
    data = WorldDataset.load(layout.dataset_path, env=ctx.env)
    config = vae_config(ctx.preset, ctx.env)
    vae = train_vae(data, config, progress=ctx.progress, checkpoint_dir=layout.generator_dir)
    generator = fit_repair(build_generator(vae, data, repair_name=ctx.preset.repair), data)
    save_generator(layout.generator_dir, vae, layout.dataset_path, generator)
    quality = assess(generator, vae, data, QUALITY_SAMPLES, jax.random.key(ctx.seed), ctx.preset.accept_generator, progress=ctx.progress)
    warnings, verdict, kept_epoch = quality["warnings"], quality["gate"], quality["training"]["kept_epoch"]
    quality_path = write_text(layout.quality_path, json.dumps(quality, indent=1))
    if verdict["verdict"] == "rejected":
        raise WorldagentError(
            f"{ctx.env}'s generator fails its quality gate ({gate_kinds(warnings)}; {layout.rel(quality_path)} says why): rerun with "
            "--accept-generator to use it anyway (recorded in the manifest and the report), or with another --repair or a larger --preset."
        )
    traversals = traversal_sheet(generator, layout.figure("generator_traversals"))
    accuracy = quality["reconstruction"]["vae"]["accuracy"]
    flagged = f"; gate {verdict['verdict']} ({gate_kinds(warnings)}: {verdict['waiver']})" if warnings else "; gate passed"
    return {
        "generator": layout.rel(layout.generator_dir),
        "quality": layout.rel(quality_path),
        "traversals": layout.rel(traversals),
        "final_loss": vae.kept["holdout_loss"],
        "warnings": warnings,
        "gate": verdict,
        "summary": f"{len(vae.history)} epochs (kept {kept_epoch}), held-out loss {vae.kept['holdout_loss']:.1f}, "
        f"cell accuracy {accuracy:.3f}{flagged}",
    }


# -- phase 2: agents (paper §4.3, §5.3) -----------------------------------------------------------


def last_values(curve: dict, names) -> dict[str, float]:
    """The learning curve's last value of each of ``names`` it holds."""
    return {name: float(np.asarray(curve[name])[-1]) for name in names if name in curve and len(curve[name])}


def agent_phase(ctx: EnvContext) -> dict:
    """Train the agents (resuming their checkpoint): on the procedural worlds of the dataset (``dr``, the
    default), or with the preset's adaptive curriculum over G(z) of the run's generator (``--curriculum``)."""
    from worldagent.agents.training import train
    from worldagent.curricula import label

    layout, spec = ctx.layout, ctx.spec
    distribution, described = training_worlds(ctx)
    result = train(
        spec,
        ctx.algo,
        ctx.train_config(ctx.budgets.episodes),
        distribution,
        layout.agent_dir,
        seed=ctx.seed,
        options=ctx.options,
        progress=ctx.progress,
        resume=True,
        distribution_spec=described,
    )
    last = last_values(result.curve, (spec.metrics.main, *spec.metrics.highlighted))
    shown = ", ".join(f"{name} {value:.3g}" for name, value in last.items())
    favoured = {}
    if getattr(distribution, "adaptive", False):  # the buffer's favourites, replayed on fresh episodes (found beside confirmed)
        from worldagent.analysis.favoured import confirm_last_favoured

        with ctx.store() as store:
            favoured = confirm_last_favoured(
                store, ctx.setup(), layout.agent_dir, distribution, repeats=ctx.preset.confirm, seed=ctx.seed, progress=ctx.progress
            )
    return {
        "agent": layout.rel(layout.agent_dir / "policy"),
        "curve": layout.rel(layout.agent_dir / "curve.png"),
        "algo": ctx.algo,
        **({"options": ctx.options} if ctx.options else {}),
        "episodes": result.episodes,
        "env_steps": result.env_steps,
        "train_s": round(result.wall_seconds, 2),
        "final": last,
        "curriculum": label(distribution),  # "dr", or the adaptive curriculum with its settings, as run.json records it
        **({"favoured": favoured} if favoured else {}),  # which stored confirmations are the favoured worlds' (the report re-reads them)
        "summary": f"{ctx.algo} {result.episodes:,} episodes{via(distribution)}; last update: {shown or 'no curve'}" + favoured.get("said", ""),
    }


def via(distribution: Any) -> str:
    """`` with curriculum plr`` for an adaptive curriculum, nothing for ``dr``."""
    return f" with curriculum {distribution.name}" if getattr(distribution, "adaptive", False) else ""


def training_worlds(ctx: EnvContext) -> tuple[Any, str]:
    """(what the agent phase trains on, how ``run.json`` records it): the dataset's worlds for ``dr``, else
    the preset's curriculum over G(z) of the run's generator, recorded as ``worldagent train`` records it."""
    from worldagent.agents.distributions import world_distribution

    layout, request = ctx.layout, ctx.preset.curriculum_of(ctx.env)
    if request is None:
        return world_distribution(ctx.spec, str(layout.dataset_path)), layout.rel(layout.dataset_path)
    from worldagent.agents.distributions import LatentWorlds
    from worldagent.curricula import label
    from worldagent.reproduce.presets import make_curriculum_of
    from worldagent.worlds.generator import load_generator

    generator = load_generator(layout.generator_dir, layout.dataset_path)[0]
    curriculum = make_curriculum_of(ctx.env, request, LatentWorlds(generator))
    return curriculum, f"{layout.rel(layout.generator_dir)}; curriculum {label(curriculum)}"


# -- phase 3: optimising worlds (paper §4.4, §6.1) ------------------------------------------------


def random_phase(ctx: EnvContext) -> dict:
    """Evaluate the agents on random worlds z ~ N(0, I) (paper §6.1.1, Figure 6a), and the world's share of the outcome."""
    from worldagent import experiments
    from worldagent.analysis.noise import share_line
    from worldagent.reports.results import world_share_summary

    with ctx.store() as store:
        evaluations = experiments.random_evaluation(
            store, ctx.setup(), ctx.metric, worlds=ctx.budgets.random_worlds, seed=ctx.seed, progress=ctx.progress, resume=True
        )
    scores = np.array([e.score for e in evaluations])
    share = world_share_summary(ctx.spec, evaluations, [ctx.metric])  # the world's share, from the episodes just stored
    said = share_line(share, ctx.metric)
    return {
        "store": ctx.layout.rel(ctx.layout.store_path),
        "campaign": experiments.campaign_names(ctx.metric, ctx.seed)["random"],
        "worlds": len(scores),
        "mean": float(np.nanmean(scores)),
        "share": share,
        "summary": f"{len(scores):,} worlds x {ctx.preset.repeats} episodes; mean {ctx.metric} {np.nanmean(scores):.4g} (sd {np.nanstd(scores):.3g})"
        + (f"; {said}" if said else ""),
    }


def random_scores(ctx: EnvContext) -> np.ndarray:
    """Per-world scores of the random evaluation (the baseline of Figures 6b and 7)."""
    from worldagent import experiments

    with ctx.store() as store:
        return experiments.random_scores(store, ctx.metric, ctx.seed)


def strategic_phase(ctx: EnvContext) -> dict:
    """Searches for the worlds that minimise and maximise reward (§6.1.2, Figures 1, 6b; the paper's CMA-ES, or the env's
    own optimiser: ``Preset.optimiser_of``); both worlds confirmed on fresh episodes (``analysis.confirm``), found
    beside confirmed in the outputs."""
    from worldagent import experiments
    from worldagent.analysis.confirm import agent_key
    from worldagent.influence.statistics import json_safe
    from worldagent.reports.strategic import draw_strategic, strategic_json

    setup = ctx.setup()
    with ctx.store() as store:
        result = experiments.strategic_evaluation(
            store,
            setup,
            ctx.metric,
            budget=ctx.budgets.strategic_budget,
            seed=ctx.seed,
            optimiser=ctx.preset.optimiser_of(ctx.env),
            progress=ctx.progress,
            resume=True,
            confirm=ctx.preset.confirm,
        )
        randoms = store.evaluations(experiments.campaign_names(ctx.metric, ctx.seed)["random"])
    low, high = result["min"], result["max"]
    figure = draw_strategic(setup, result, random_scores(ctx), ctx.metric, ctx.layout.figure("strategic"))
    found = strategic_json(ctx.spec, result, randoms)
    return {
        "store": ctx.layout.rel(ctx.layout.store_path),
        "campaigns": list(result["campaigns"]),
        "min": float(low.score),
        "max": float(high.score),
        "figure": ctx.layout.rel(figure),
        # which stored confirmations are these worlds' (the report re-reads them): the agent, the seed and the repeats
        "confirmation": {"agent": agent_key(setup), "seed": ctx.seed, "repeats": ctx.preset.confirm, "selections": list(result["selections"])},
        "confirmed": json_safe({side: found[side] for side in ("min", "max")}),
        "summary": f"{ctx.metric} ({ctx.budgets.strategic_budget} worlds each): " + strategic_summary(result),
    }


def strategic_summary(result: dict) -> str:
    """ "min found -281.7, confirmed -184.6 [-224.7, -144.6] (64 fresh episodes); max found ...": one line per run."""
    parts = []
    for side, confirmed in zip(("min", "max"), result["confirmed"]):
        text = f"{side} found {result[side].score:.4g}"
        if confirmed is not None:
            interval = confirmed.confirmed(result["metric"])
            text += f", confirmed {interval.text()} ({interval.n} fresh episodes)"
        parts.append(text)
    return "; ".join(parts)


def skipped_for_budget(ctx: EnvContext, budget: str) -> dict:
    """A phase's record when its budget is 0: it says so, and where to set the budget (a preset an env
    package copied without it skips the phase; issue 42)."""
    why = f"{ctx.env}'s preset {ctx.preset.name!r} gives {budget} 0"
    fix = f"set EnvSpec.presets[{ctx.preset.name!r}][{budget!r}] to run it"
    return {"skipped": f"{why}; {fix}", "summary": f"skipped: {why} ({fix})"}


def compare_names(ctx: EnvContext, optimisers=OPTIMISERS) -> dict[str, list[str]]:
    """Store names of the comparison campaigns, by optimiser."""
    from worldagent import experiments

    return experiments.comparison_campaign_names(ctx.metric, ctx.budgets.compare_seeds, optimisers)


def compare_phase(ctx: EnvContext) -> dict:
    """ES against BO against random search, all minimising reward (§6.1.3, Figure 7)."""
    budgets = ctx.budgets
    if budgets.compare_budget < 1:
        return skipped_for_budget(ctx, "compare_budget")
    from worldagent import experiments
    from worldagent.analysis.confirm import agent_key
    from worldagent.influence.statistics import json_safe
    from worldagent.reports.comparison import comparison_figure, confirmed_efficiency, ordering

    setup = ctx.setup()
    arguments = {
        "maximize": False,
        "optimisers": OPTIMISERS,
        "budget": budgets.compare_budget,
        "budgets": {"bo": budgets.bo_budget} if budgets.bo_budget else None,
        "seeds": tuple(budgets.compare_seeds),
        "progress": ctx.progress,
    }
    with ctx.store() as store:
        runs = experiments.compare_optimisers(store, setup, ctx.metric, resume=True, **arguments)
        # Figure 7 ranks by each seed's best world, partly luck: rank again on those worlds replayed on fresh episodes
        confirmed = experiments.confirm_optimisers(store, setup, ctx.metric, repeats=ctx.preset.confirm, seed=ctx.seed, **arguments)
    rows = confirmed_efficiency(runs, confirmed, ctx.metric)
    figure = comparison_figure(runs, random_scores(ctx), ctx.metric, ctx.layout.figure("comparison"), maximize=False, confirmed=rows)
    best = {opt: float(np.nanmin(np.concatenate([np.ravel(r) for r in scores]))) for opt, scores in runs.items()}
    verdict = ordering(rows, confirmed, ctx.metric)
    means = ", ".join(f"{row['optimiser']} {row['confirmed_mean']:.4g}" for row in sorted(rows, key=lambda row: row["rank"]))
    found, selection = ", ".join(f"{opt} {value:.4g}" for opt, value in best.items()), experiments.comparison_selection_name(False, ctx.metric)
    return {
        "store": ctx.layout.rel(ctx.layout.store_path),
        "campaigns": compare_names(ctx, tuple(runs)),
        "best": best,
        "figure": ctx.layout.rel(figure),
        "confirmation": {"agent": agent_key(setup), "seed": ctx.seed, "repeats": ctx.preset.confirm, "selection": selection},
        "confirmed": json_safe(rows),
        "ordering": json_safe(verdict),
        "summary": f"lowest found {found}; confirmed ({ctx.preset.confirm} fresh episodes, mean over seeds) {means}; the paper's ordering: {verdict['verdict']}",
    }


# -- influencing (paper §6.2) --------------------------------------------------------------------


def influence_phase(ctx: EnvContext) -> dict:
    """Retrain agents on worlds with a desired property and compare them with default training (§6.2, Figure 8).
    The agents train only on selected worlds whose property holds on ``influence_confirm`` fresh episodes each
    (``influence.confirmation``); when none does, that is the phase's finding, recorded, and the run goes on."""
    from worldagent import experiments
    from worldagent.influence.confirmation import NoneSurvived
    from worldagent.influence.statistics import json_safe
    from worldagent.reports.influence import influence_figure

    budgets, layout = ctx.budgets, ctx.layout
    setup = ctx.setup()
    try:
        result = experiments.influence(
            layout.influence_dir,
            setup,
            ctx.preset.selection(ctx.env),
            algo=ctx.algo,
            episodes=budgets.influence_episodes,
            seeds=tuple(budgets.influence_seeds),
            candidates=budgets.influence_candidates,
            search_budget=budgets.influence_search_budget,
            search=budgets.influence_search,
            eval_worlds=budgets.influence_eval_worlds,
            config=ctx.train_config(budgets.influence_episodes),
            seed=ctx.seed,
            progress=ctx.progress,
            confirm=ctx.preset.influence_confirm,
        )
    except NoneSurvived as error:
        return {"skipped": str(error), "confirmation": json_safe(error.summary), "summary": f"no influenced agents: {error}"}
    examples = experiments.example_worlds(layout.influence_dir, setup.spec)
    figure = influence_figure(result, examples, setup.spec, layout.figure("influence"))
    return {
        "influence": layout.rel(layout.influence_result),
        "figure": layout.rel(figure),
        "selection": ctx.preset.selection(ctx.env),
        "selected": result["worlds"]["selected"],
        "summary": influence_summary(result),
    }


def influence_summary(result: dict) -> str:
    """One line: how many worlds were selected, and each compared metric, default -> influenced."""
    summary = result.get("summary", {})
    worlds = result.get("worlds", {})
    confirmation = worlds.get("confirmation")
    if confirmation is None:
        parts = [f"{worlds.get('selected', '?')} worlds selected"]
    else:  # the agents trained on the survivors only
        parts = [
            f"{confirmation['survived']} of {confirmation['selected']} selected worlds kept the property on {confirmation['repeats']} fresh episodes"
        ]
    for metric, by_label in summary.items():
        parts.append(f"{metric} {by_label['default']['mean']:.3g} -> {by_label['influenced']['mean']:.3g}")
    parts += [f"WARNING: the {name} agent {why}" for name, why in result.get("failed_training", {}).items()]
    return "; ".join(parts)


# -- beyond the paper: the failure atlas ----------------------------------------------------------

ATLAS_CELLS = 10  # cells per descriptor of the atlas's grid (the spec's default descriptors)
IMPORTANCE_ROUNDS = 4  # rounds of the importance sampler's search, each of a quarter of failure_worlds
POOL_PER_WORLD = 20  # the surrogate's pool of described prior worlds, per world it samples (paper racing: 200,000)


def atlas_phase(ctx: EnvContext) -> dict:
    """A failure atlas of the agents (CMA-ME over the spec's default descriptors) with every elite confirmed on
    fresh episodes (the corrected archive, found beside confirmed), why its failures happen (nearest passing
    worlds, failure groups), and how likely ``spec.failure`` is (Monte Carlo and importance sampling)."""
    budgets, layout, spec = ctx.budgets, ctx.layout, ctx.spec
    if budgets.atlas_budget < 1:
        return skipped_for_budget(ctx, "atlas_budget")
    from worldagent import experiments
    from worldagent.analysis.confirm import agent_key
    from worldagent.reports.atlas import atlas_figure, counterfactual_figure

    setup, failure = ctx.setup(), spec.failure or None
    with ctx.store() as store:
        found = experiments.atlas(
            store,
            setup,
            ctx.metric,
            budget=budgets.atlas_budget,
            seed=ctx.seed,
            cells=ATLAS_CELLS,
            failure=failure,
            progress=ctx.progress,
            confirm=ctx.preset.elite_confirm,
        )
        loaded = lambda e: (experiments.with_world(store, e), experiments.scored_keys_of(store, e))  # noqa: E731
        figure = atlas_figure(found, setup, ctx.metric, False, loaded, layout.figure("atlas"))
        outputs = {
            "store": layout.rel(layout.store_path),
            "campaign": found["evaluations"][0].campaign,
            "figure": layout.rel(figure),
            "failure": failure,
            # which stored confirmations are the elites' (the report re-reads them): the agent, the seed and the repeats
            "confirmation": {"agent": agent_key(setup), "seed": ctx.seed, "repeats": ctx.preset.elite_confirm},
        }
        if failure:
            explained = experiments.explain_failures(setup, found, experiments.failure_selection(failure, ctx.env), seed=ctx.seed)
            pairs = counterfactual_figure(setup, explained["pairs"], layout.figure("atlas_counterfactuals"))
            outputs["counterfactuals"] = layout.rel(pairs)
            outputs["pairs"] = [{"t_failing": p["boundary"].t_failing, "t_passing": p["boundary"].t_passing} for p in explained["pairs"]]
            outputs["estimates"] = failure_rates(ctx, store, setup) if budgets.failure_worlds else {}
    rates = "; ".join(f"{m} P = {e['estimate']:.3g}" if "estimate" in e else f"{m}: {e['error']}" for m, e in outputs.get("estimates", {}).items())
    failing = "" if found["distinct_failing"] is None else f", {found['distinct_failing']} distinct failing worlds"
    summary = f"coverage {found['coverage']:.2f}, QD-score {found['qd_score']:.4g}{failing}"
    confirmed = found["confirmed"]
    if confirmed is not None:
        outputs["confirmed"] = {key: confirmed[key] for key in ("repeats", "elites", "distinct_worlds", "episodes", "found", "confirmed")}
        outputs["confirmed"]["no_longer_failing"] = confirmed.get("no_longer_failing", [])
        fresh = confirmed["confirmed"]
        cells = ""
        if "failing_cells" in fresh:
            cells = f", failing cells found {confirmed['found']['failing_cells']} -> confirmed {fresh['failing_cells']}"
        summary += f" (found); elites on {confirmed['repeats']} fresh episodes: QD-score {fresh['qd_score']:.4g}{cells}"
    outputs["summary"] = summary + (f"; {rates}" if rates else "")
    return outputs


def failure_rates(ctx: EnvContext, store, setup) -> dict[str, dict]:
    """{method: estimate as a dict, or {"error": why}} of ``spec.failure`` (importance sampling fails
    when its search never meets the event; Monte Carlo's bound is still a result)."""
    from worldagent import experiments
    from worldagent.analysis.failure_rate import ImportanceConfig

    worlds = ctx.budgets.failure_worlds
    importance = ImportanceConfig(
        round_worlds=max(20, worlds // 4), max_rounds=IMPORTANCE_ROUNDS, pilot=max(20, worlds // 4), pool=POOL_PER_WORLD * worlds
    )
    found = {}
    for method in ("mc", "is"):
        try:
            estimate = experiments.failure_rate(
                store, setup, ctx.spec.failure, method=method, worlds=worlds, importance=importance, seed=ctx.seed, progress=ctx.progress
            )[method]
            found[method] = estimate.as_dict()
        except WorldagentError as error:
            found[method] = {"error": str(error)}
    return found


PHASE_FUNCTIONS: dict[str, Callable[[EnvContext], dict]] = {
    "dataset": dataset_phase,
    "generator": generator_phase,
    "agent": agent_phase,
    "random": random_phase,
    "strategic": strategic_phase,
    "compare": compare_phase,
    "influence": influence_phase,
    "atlas": atlas_phase,
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
    "atlas": ("generator", "agent"),
}
# An agent trained with an adaptive curriculum drew its worlds from G(z): it is computed from the generator too.
CURRICULUM_DEPENDS = {**DEPENDS, "agent": ("dataset", "generator")}


def dependents(phase: str, curriculum: bool = False) -> list[str]:
    """``phase`` and every phase computed (directly or not) from it, in pipeline order; ``curriculum``:
    the agents train with an adaptive curriculum (``Preset.curriculum_of``), over G(z)."""
    depends = CURRICULUM_DEPENDS if curriculum else DEPENDS
    if phase not in depends:
        raise WorldagentError(f"unknown phase {phase!r}; use one of: {', '.join(depends)}.")
    found = {phase}
    changed = True
    while changed:
        changed = False
        for name, parents in depends.items():
            if name not in found and found.intersection(parents):
                found.add(name)
                changed = True
    return [name for name in depends if name in found]
