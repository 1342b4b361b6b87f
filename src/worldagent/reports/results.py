"""The numbers of the report, recomputed from a run's stores (never copied from a phase's log).

Normalisation (paper §6: "we normalise all reported metrics to be between 0 and 1") is the
environment's (``spec.metrics.normalise``): by the main metric's rule-given range where the env
registers ``bounds`` (racing), otherwise by the largest single-episode value of the main metric
among all the run's evaluated worlds of that env (harvest; the best episode scores 1, a world's
mean stays below).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from worldagent.envs import registry
from worldagent.runs import Run


@dataclass(frozen=True)
class Headline:
    """One headline number: ours (from the store) beside the paper's."""

    key: str
    label: str
    ours: float | None
    paper: float | None
    note: str = ""


@dataclass(frozen=True)
class Scale:
    """How one run normalises an env's main metric: the env's params and the run's best episode."""

    params: Any
    best_episode: float | None


def world_means(evaluations, metric: str) -> np.ndarray:
    """f64[worlds]: each evaluated world's mean of ``metric`` over its episodes."""
    return np.array([np.nanmean([np.nan if e.get(metric) is None else float(e[metric]) for e in ev.episodes]) for ev in evaluations], np.float64)


def run_scale(spec, store) -> Scale:
    """The params ``reproduce`` ran the env with, and the store's best single episode of the main metric."""
    main = spec.metrics.main
    best = max((float(e[main]) for ev in store.iter_evaluations() for e in ev.episodes if e.get(main) is not None), default=None)
    return Scale(spec.make_env(spec.reproduce_options)[1], best)


def normalised_means(spec, evaluations, scale: Scale) -> np.ndarray:
    """f64[worlds]: each world's mean of its episodes' normalised main metric (``spec.metrics.normalise``)."""
    main = spec.metrics.main
    values = [[np.nan if e.get(main) is None else float(e[main]) for e in ev.episodes] for ev in evaluations]
    return np.array([np.nanmean(spec.metrics.normalise(v, scale.params, scale.best_episode)) for v in values], np.float64)


def best_evaluation(evaluations, maximize: bool):
    """The lowest- (or highest-) scoring evaluation; the earliest on ties."""
    finite = [e for e in evaluations if np.isfinite(e.score)]
    if not finite:
        return None
    scores = np.array([e.score for e in finite])
    return finite[int(np.argmax(scores) if maximize else np.argmin(scores))]


def world_summary(spec, evaluation, scale: Scale) -> dict:
    """Raw score, normalised score and the highlighted metrics (e.g. crash rate) of one evaluated world, and where its
    latent lies under the prior (``search.prior.prior_summary``; None without a latent)."""
    from worldagent.search.prior import prior_summary

    return {
        "raw": float(evaluation.score),
        "normalised": float(normalised_means(spec, [evaluation], scale)[0]),
        "campaign": evaluation.campaign,
        "generation": evaluation.generation,
        "slot": evaluation.slot,
        **{name: float(world_means([evaluation], name)[0]) for name in spec.metrics.highlighted},
        "prior": prior_summary(evaluation.latent) if np.size(evaluation.latent) else None,  # issue 48: |z| under G's prior
    }


def env_results(run: Run, env: str) -> dict:
    """Everything the report shows about one environment, recomputed from what ``run`` reads."""
    spec, done = registry.get(env), run.phases(env)
    results: dict[str, Any] = {"phases": done, "metric": spec.metrics.main, "layout": run.layout(env)}
    if run.has_store(env):
        with run.store(env) as store:
            results.update(store_results(spec, store, done))
            if "campaign" in run.outputs(env, "atlas"):
                results["atlas"] = atlas_results(spec, store, done["atlas"]["outputs"])
    for name, found in (("influence", run.influence(env)), ("quality", run.quality(env)), ("curriculum", run.curriculum(env))):
        if found is not None:
            results[name] = found
    return results


def played_failure(spec, evaluations):
    """The env's failure event (``spec.failure``) parsed, when every evaluation played its metrics; else None."""
    from worldagent.events import parse_selection

    if not spec.failure or not evaluations:
        return None
    selection = parse_selection(spec.failure, spec.name)
    played = all(any(m in e for e in ev.episodes) for ev in evaluations for m in selection.metrics)
    return selection if played else None


def world_share_summary(spec, evaluations, metrics=()) -> dict:
    """The world's share (``analysis.noise.noise_summary``, strict JSON: NaN as null) of ``metrics`` and the env's
    main metric, and of its failure event where played; {} when the worlds hold fewer than 2 episodes each."""
    from worldagent.analysis.noise import noise_summary
    from worldagent.influence.statistics import json_safe

    names = [m for m in dict.fromkeys([*metrics, spec.metrics.main]) if m]
    return json_safe(noise_summary(evaluations, names, played_failure(spec, evaluations)))


def random_results(spec, evaluations, campaign: str, scale: Scale) -> dict:
    """Means over the random worlds: raw, normalised and each highlighted metric; the world's share (``world_share_summary``)."""
    normalised = normalised_means(spec, evaluations, scale)
    return {
        "campaign": campaign,
        "worlds": len(evaluations),
        "scores": np.array([e.score for e in evaluations]),
        "normalised": normalised,
        "mean_raw": float(np.nanmean([e.score for e in evaluations])),
        "mean_normalised": float(np.nanmean(normalised)),
        **{name: float(np.nanmean(world_means(evaluations, name))) for name in spec.metrics.highlighted},
        "share": world_share_summary(spec, evaluations),
    }


def store_results(spec, store, done: dict) -> dict:
    """Random, strategic and comparison numbers of one environment's store."""
    scale = run_scale(spec, store)
    out: dict[str, Any] = {"scale": scale}
    if done["random"].get("status") == "done":
        campaign = done["random"]["outputs"]["campaign"]
        out["random"] = random_results(spec, store.evaluations(campaign), campaign, scale)
    if done["strategic"].get("status") == "done":
        low_name, high_name = done["strategic"]["outputs"]["campaigns"]
        for label, name, maximize in (("min", low_name, False), ("max", high_name, True)):
            evaluations = store.evaluations(name)
            found = best_evaluation(evaluations, maximize)
            if found is not None:
                campaign = store.campaign(name)
                out[label] = {**world_summary(spec, found, scale), "evaluated": len(evaluations), "optimiser": campaign.optimiser if campaign else ""}
                confirmed = stored_confirmation(spec, store, found, done["strategic"]["outputs"].get("confirmation"))
                if confirmed is not None:
                    out[label]["confirmed"] = confirmed_world_summary(spec, confirmed, scale)
    compare = done["compare"]
    if compare.get("status") == "done" and "campaigns" in compare.get("outputs", {}) and "random" in out:
        config = compare["config"]
        budget = {opt: config.get("bo_budget", config["budget"]) if opt == "bo" else config["budget"] for opt in compare["outputs"]["campaigns"]}
        stored = {opt: [store.evaluations(name)[: budget[opt]] for name in names] for opt, names in compare["outputs"]["campaigns"].items()}
        runs = {opt: [np.array([e.score for e in seed], np.float64) for seed in seeds] for opt, seeds in stored.items()}
        out["compare"] = {"runs": runs}
        confirmed = compare_confirmations(spec, store, stored, compare["outputs"].get("confirmation"))
        if confirmed:
            out["compare"]["confirmed"] = confirmed
    return out


def stored_confirmation(spec, store, evaluation, confirmation: dict | None):
    """The ``analysis.confirm.ConfirmedWorld`` of a reported evaluation, read back from the store: the world a selection
    recorded for its (campaign, generation, slot), replayed for the phase's ``confirmation`` (agent, seed, repeats);
    None when the phase confirmed nothing (runs from before confirmation) or the row is missing."""
    from worldagent.analysis.confirm import ConfirmedWorld, confirmation_seed

    if not confirmation:
        return None
    place = (evaluation.campaign, evaluation.generation, evaluation.slot)
    digests = [s.world for s in store.selections() if (s.campaign, s.generation, s.slot) == place]
    seed, repeats = int(confirmation["seed"]), int(confirmation["repeats"])
    for row in store.confirmations(confirmation["agent"], spec.name):
        if digests and row.world == digests[-1] and (row.seed, row.repeats) == (seed, repeats):
            return ConfirmedWorld(evaluation, row.world, row.episodes, confirmation_seed(seed, row.world))
    return None


def confirmed_world_summary(spec, confirmed, scale: Scale) -> dict:
    """A confirmed world's fresh-episode figures, each a mean with its 95% interval (``analysis.confirm.Interval``):
    the main metric raw and normalised, and each highlighted metric; and the episodes they came from."""
    from worldagent.analysis.confirm import mean_interval, metric_values

    raw = metric_values(confirmed.episodes, spec.metrics.main)
    normalised = np.asarray(spec.metrics.normalise(raw, scale.params, scale.best_episode), np.float64)
    return {
        "repeats": confirmed.repeats,
        "raw": confirmed.confirmed(spec.metrics.main).as_dict(),
        "normalised": mean_interval(normalised).as_dict(),
        **{name: confirmed.confirmed(name).as_dict() for name in spec.metrics.highlighted},
    }


def compare_confirmations(spec, store, stored: dict, confirmation: dict | None) -> dict:
    """{optimiser: [ConfirmedWorld of each seed's reported world]} read back from the store; {} unless every seed's is there."""
    confirmed = {}
    for opt, seeds in stored.items():
        picks = [best_evaluation(seed, False) for seed in seeds]  # the phase minimises (Figure 7)
        worlds = [None if pick is None else stored_confirmation(spec, store, pick, confirmation) for pick in picks]
        if not worlds or any(world is None for world in worlds):
            return {}
        confirmed[opt] = worlds
    return confirmed


def atlas_results(spec, store, outputs: dict) -> dict:
    """The atlas phase's numbers recomputed from the store: the archive's coverage and QD-score, the corrected
    archive's (its elites' stored confirmations), the failing and distinct failing worlds, their groups, and each
    failure-rate estimate replayed."""
    from worldagent.analysis import failure_rate as fr
    from worldagent.analysis.explanations import clusters
    from worldagent.analysis.stored import campaign_name, read_estimate
    from worldagent.errors import WorldagentError
    from worldagent.events import parse_selection
    from worldagent.search.atlas import distinct_count, qd_offset, read_atlas
    from worldagent.search.corrected_atlas import corrected_summary, stored_elites

    atlas = read_atlas(store, outputs["campaign"])
    scores = np.array([e.score for e in atlas.evaluations], np.float64)
    offset = qd_offset(scores, atlas.maximize)
    found: dict[str, Any] = {
        "atlas": atlas,
        "evaluations": len(atlas.evaluations),
        "coverage": atlas.archive.coverage(atlas.grid),
        "qd_score": atlas.archive.qd_score(offset, atlas.maximize),
    }
    selection = parse_selection(outputs["failure"], spec.name) if outputs.get("failure") else None
    kept = outputs.get("confirmation")
    elites = stored_elites(store, atlas, kept["agent"], kept["seed"], kept["repeats"]) if kept else None
    if elites is not None:
        found["confirmed"] = corrected_summary(atlas.grid, atlas.archive, elites, atlas.campaign.objective, offset, atlas.maximize, selection)
    if selection is None:
        return found
    failing = np.flatnonzero(selection.mask(atlas.evaluations))
    latents = np.stack([atlas.evaluations[i].latent for i in failing]) if len(failing) else np.zeros((0, 1))
    found |= {
        "selection": selection,
        "failing": len(failing),
        "distinct_failing": distinct_count([atlas.evaluations[i].world for i in failing]),
        "clusters": clusters(atlas.measures[failing], latents, seed=atlas.campaign.seed),
        "failing_measures": atlas.measures[failing],
        "estimates": {},
    }
    for method in fr.METHODS:
        name = campaign_name(method, selection.text, atlas.campaign.seed)
        if store.campaign(name) is not None:
            try:
                found["estimates"][method] = read_estimate(store, name)
            except WorldagentError as error:  # e.g. importance sampling that never met the event
                found["estimates"][method] = str(error)
    return found


def pick(source: Any, *path) -> float | None:
    """``source[path[0]][path[1]]...`` as a float, None when any step is missing."""
    for step in path:
        if not isinstance(source, dict) or step not in source:
            return None
        source = source[step]
    return float(source) if source is not None else None


def label(name: str) -> str:
    return name.replace("_", " ")


def headlines(results: dict[str, dict]) -> list[Headline]:
    """The paper's headline numbers (§6.1–§6.2, ``spec.paper``) beside ours, for every environment of the run."""
    rows: list[Headline] = []
    for env, res in results.items():
        spec = registry.get(env)
        paper, main, title = spec.paper, spec.metrics.main, env.capitalize()
        rows.append(
            Headline(
                f"{env}.random.mean_normalised",
                f"{title}: random worlds, mean {label(main)} (normalised)",
                pick(res, "random", "mean_normalised"),
                paper.get("random.mean_normalised"),
            )
        )
        rows.append(Headline(f"{env}.random.mean_raw", f"{title}: random worlds, mean {label(main)} (raw)", pick(res, "random", "mean_raw"), None))
        rows += [
            Headline(f"{env}.random.{m}", f"{title}: random worlds, {label(m)}", pick(res, "random", m), paper.get(f"random.{m}"))
            for m in spec.metrics.highlighted
        ]
        for side in ("min", "max"):
            if pick(res, side, "confirmed", "raw", "mean") is not None:
                rows += confirmed_headlines(env, side, res[side], main, paper, spec.metrics.highlighted)
                continue
            world = f"{title}: {side}imising world"
            rows.append(
                Headline(
                    f"{env}.{side}.normalised", f"{world}, {label(main)} (normalised)", pick(res, side, "normalised"), paper.get(f"{side}.normalised")
                )
            )
            rows.append(Headline(f"{env}.{side}.raw", f"{world}, {label(main)} (raw)", pick(res, side, "raw"), None))
            rows += [
                Headline(f"{env}.{side}.{m}", f"{world}, {label(m)}", pick(res, side, m), paper.get(f"{side}.{m}")) for m in spec.metrics.highlighted
            ]
        rows += influence_headlines(env, res)
    return rows


def confirmed_headlines(env: str, side: str, found: dict, main: str, paper: dict, highlighted) -> list[Headline]:
    """A strategic world's headline rows when it was confirmed: ours is the confirmed figure (fresh episodes; the
    paper's number beside it), the found one (the selection's, biased by the pick) in the note and in a row of its own."""
    confirmed, world = found["confirmed"], f"{env.capitalize()}: {side}imising world"
    rows = []
    for name, shown in ((main, "normalised"), (main, "raw"), *[(m, m) for m in highlighted]):
        fresh = confirmed[shown]
        what = f"{label(name)} ({shown})" if name == main else label(name)
        note = (
            f"confirmed on {fresh['episodes']} fresh episodes, 95% [{fresh['low']:.3g}, {fresh['high']:.3g}]; "
            f"found {found[shown]:.3g} (the selection's, the search's episodes)"
        )
        paper_value = paper.get(f"{side}.{shown}") if shown != "raw" else None
        rows.append(Headline(f"{env}.{side}.confirmed.{shown}", f"{world}, {what}, confirmed", fresh["mean"], paper_value, note))
        rows.append(Headline(f"{env}.{side}.{shown}", f"{world}, {what}, found (the selection's)", found[shown], None))
    return rows


def influence_headlines(env: str, res: dict) -> list[Headline]:
    """Default and influenced means (over seeds) of the highlighted metrics, and the main metric's change in %."""
    spec = registry.get(env)
    summary = (res.get("influence") or {}).get("summary", {})
    seeds = len(((res.get("influence") or {}).get("config") or {}).get("seeds", ())) or None
    note = "one seed per arm: no direction can be read" if seeds == 1 else ""
    rows = [
        Headline(
            f"{env}.influence.{metric}_{which}",
            f"{env.capitalize()} influence: {label(metric)}, {which} training",
            pick(summary, metric, which, "mean"),
            spec.paper.get(f"influence.{metric}.{which}"),
            note,
        )
        for metric in spec.metrics.highlighted
        for which in ("default", "influenced")
    ]
    rows.append(
        Headline(
            f"{env}.influence.reward_change_pct",
            f"{env.capitalize()} influence: reward change, % (normalised)",
            reward_change(spec, res),
            spec.paper.get("influence.reward_change_pct"),
            note,
        )
    )
    return rows


def reward_change(spec, res: dict) -> float | None:
    """100 · (influenced − default) / |default| of the normalised main metric's means, None when unknown."""
    main = (res.get("influence") or {}).get("summary", {}).get(spec.metrics.main, {})
    before, after = pick(main, "default", "mean"), pick(main, "influenced", "mean")
    scale = res.get("scale")
    if before is None or after is None or scale is None:
        return None
    before, after = (float(spec.metrics.normalise(v, scale.params, scale.best_episode)) for v in (before, after))
    return 100.0 * (after - before) / abs(before) if before and np.isfinite(before) and np.isfinite(after) else None
