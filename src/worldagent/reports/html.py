"""The HTML report of a ``reproduce`` run: one self-contained file, opens offline.

``build_report(run_dir)`` reads ``manifest.json`` and, for every environment the run names,
the numbers ``results.env_results`` recomputes from its run store, the generator's
``quality.json``, the agents' learning curves and ``influence.json`` (where each lives:
``runs.RunLayout``, read through ``runs.Run``), and writes ``run_dir/report.html``: inline CSS, every figure a
base64 PNG. It reads like a result: where this run departs from the paper first (``departures``: the
settings unlike the paper's preset, the generator's gate warnings, each gap with the possible causes the
run's own record shows and a link to its section), the headline numbers beside the paper's, then the
figures behind them, the provenance (versions, phases, the preset) last and folded; it ends its
headline section with the ``worldagent explore`` command that opens the same run interactively.
Each headline number is printed next to the paper's value (``spec.paper``) and
carries ``data-key`` / ``data-value`` attributes so tests and scripts can read it back exactly.
Figures that are pure functions of the store (Figures 6a and 7) are redrawn here; those that
replay agents (Figures 1/6b and 8) were drawn by their phase and are embedded. A phase that has
not run (or failed) shows as such; the report is built from whatever is there. This module
only renders: the numbers are ``results``'s, the HTML pieces ``page``'s.
"""

from __future__ import annotations

from pathlib import Path

from worldagent.envs import registry
from worldagent.files import write_text
from worldagent.reports.curriculum import curriculum_section
from worldagent.reports.departures import departures_section, differs, seeds_of
from worldagent.reports.influence import training_regime
from worldagent.reports.noise import share_paragraph
from worldagent.reports.page import CSS, esc, fmt, image, missing, number, phase_state, section, table
from worldagent.reports.provenance import overview
from worldagent.reports.results import Headline, env_results, headlines
from worldagent.runs import Run
from worldagent.search.names import OPTIMISER_WORDS

REPORT_FILE = "report.html"
# The result first (ours beside the paper's), then the figures behind it, provenance last and folded.
SECTIONS = (
    ("departures", "Where this run departs from the paper"),
    ("headline", "Headline numbers, ours beside the paper's"),
    ("random", "Random evaluation (Figure 6a)"),
    ("strategic", "Strategic evaluation (Figures 1, 6b)"),
    ("comparison", "Optimiser comparison (Figure 7)"),
    ("influence", "Influencing (Figure 8)"),
    ("atlas", "Failure atlas (beyond the paper)"),
    ("generator", "Generator quality"),
    ("training", "Training curves"),
    ("curriculum", "Curriculum"),
    ("provenance", "Provenance"),
)


# -- sections -------------------------------------------------------------------------------


def highlighted(env: str) -> tuple[str, ...]:
    """The metrics shown beside the main one (``spec.metrics.highlighted``, e.g. racing's crash rate)."""
    return registry.get(env).metrics.highlighted


def per_env(results: dict, phase: str, render, needs: str | None = None, absent: str = "") -> str:
    """One ``<h3>`` block per environment: the phase's state when it is not done, ``absent`` when
    its results lack ``needs``, else ``render(env, res)``; "not run" when there is no environment."""
    parts = []
    for env, res in results.items():
        parts.append(f"<h3>{env}</h3>")
        state = phase_state(res["phases"][phase])
        if state or (needs and needs not in res):
            parts.append(state or missing(absent))
        else:
            parts.append(render(env, res))
    return "".join(parts) or missing("not run")


def kept_loss_row(training: dict) -> list[str]:
    """The held-out loss of the weights G(z) uses: the kept epoch's (training keeps its best held-out epoch), else the last."""
    kept = training.get("kept")
    if kept is None:  # trained before the best epoch was kept
        return ["final held-out loss", fmt(training["final"]["holdout_loss"])]
    return [f"held-out loss of the kept epoch ({training['kept_epoch']} of {training['epochs']})", fmt(kept["holdout_loss"])]


def generator_section(run_dir: Path, results: dict) -> str:
    def render(env: str, res: dict) -> str:
        quality = res["quality"]
        recon = quality["reconstruction"]
        rows = [
            ["reconstruction: cell accuracy (VAE / mean image)", f"{fmt(recon['vae']['accuracy'])} / {fmt(recon['mean_image']['accuracy'])}"],
            ["reconstruction: on-cell IoU (VAE / mean image)", f"{fmt(recon['vae']['iou'])} / {fmt(recon['mean_image']['iou'])}"],
            ["held-out worlds", fmt(recon["worlds"])],
            ["training epochs", fmt(quality["training"]["epochs"])],
            kept_loss_row(quality["training"]),
        ]
        figures = quality.get(env, {})
        rows += [[name.replace("_", " "), fmt(value)] for name, value in figures.items() if not isinstance(value, dict)]
        rows += latent_rows(figures)
        if figures.get("coverage"):  # G(z) against fresh procedural worlds (worlds.coverage); older quality.json files lack it
            cover, names = figures["coverage"], ("precision", "recall", "density", "coverage")
            floor = f" (fresh against fresh: {' / '.join(fmt(cover['floor'][n], 3) for n in names)})" if cover.get("floor") else ""
            rows.append([f"against {fmt(cover['worlds'])} fresh worlds: {' / '.join(names)}", " / ".join(fmt(cover[n], 3) for n in names) + floor])
        return (
            warnings_list(quality.get("warnings", []))
            + table(["measure", "value"], rows)
            + structure_table(figures.get("structure", {}))
            + image(res["layout"].figure("generator_traversals"), f"{env}: latent traversals of G(z) (one row per latent dimension)")
        )

    return per_env(results, "generator", render, "quality", "no quality.json")


def warnings_list(warnings: list[str]) -> str:
    """The generator's one-line warnings (collapsed, inert, narrow; ``quality.json``'s "warnings"), first and in colour."""
    if not warnings:
        return ""
    return "<ul class='warning'>" + "".join(f"<li>{esc(line)}</li>" for line in warnings) + "</ul>"


def latent_rows(figures: dict) -> list[list[str]]:
    """Rows of the latent's use and G(z)'s sensitivity (absent from quality.json files written before them)."""
    rows = []
    if "latent" in figures:
        latent = figures["latent"]
        rows.append(["latent: KL, nats (active units)", f"{fmt(latent['kl_total'])} ({latent['active_units']} of {len(latent['kl_per_dim'])})"])
    if "sensitivity" in figures:
        rows.append(["worlds changed by a ±1 move along z", fmt(figures["sensitivity"]["mean_changed_world_share"])])
    return rows


def structure_table(structure: dict) -> str:
    """The generator's worlds against the dataset's, one row per structural feature (``quality.json``'s "structure")."""
    if not structure:
        return ""
    rows = [
        [
            name.replace("_", " "),
            fmt(v.get("generator")),
            fmt(v.get("dataset")),
            fmt(None if v.get("relative_difference") is None else 100 * v["relative_difference"], 3),
            fmt(v.get("spread_ratio"), 3),
        ]
        for name, v in structure.items()
    ]
    head = ["feature", "G(z)", "dataset", "difference, %", "std G(z) / dataset"]
    return "<h4>Structure: worlds G(z) against the dataset's (means, spread)</h4>" + table(head, rows)


def explorer_hint(run_dir: Path) -> str:
    """How to look at the same run interactively."""
    return (
        "<p class='explore'>To look at these worlds yourself (every stored world on a map of the latent space, "
        "worlds decoded and played live, the atlas and the failures), open the run in the explorer: "
        f"<code>worldagent explore {esc(run_dir)}</code> (docs/explorer.md).</p>"
    )


def training_section(run_dir: Path, results: dict) -> str:
    def render(env: str, res: dict) -> str:
        outputs = res["phases"]["agent"]["outputs"]
        rows = [
            ["algorithm", outputs.get("algo")],
            ["episodes", fmt(outputs.get("episodes"))],
            ["env steps", fmt(outputs.get("env_steps"))],
            ["training s", fmt(outputs.get("train_s"))],
        ] + [[f"last: {k}", fmt(v)] for k, v in outputs.get("final", {}).items()]
        return table(["", ""], rows) + image(run_dir / outputs["curve"], f"{env}: learning curve")

    return per_env(results, "agent", render)


def random_section(run_dir: Path, results: dict) -> str:
    from worldagent.reports.figures import distribution_figure

    def render(env: str, res: dict) -> str:
        random = res["random"]
        rows = [
            [f"<td>worlds x episodes</td><td class='num'>{random['worlds']} x {res['phases']['random']['config']['repeats']}</td>"],
            ["<td>mean reward (raw)</td>" + number(f"{env}.random.mean_raw", random["mean_raw"])],
            ["<td>mean reward (normalised)</td>" + number(f"{env}.random.mean_normalised", random["mean_normalised"])],
        ]
        rows += [[f"<td>mean {name.replace('_', ' ')}</td>" + number(f"{env}.random.{name}", random[name])] for name in highlighted(env)]
        figure = distribution_figure(
            {"random worlds": random["normalised"]},
            f"{res['metric']} (normalised)",
            res["layout"].figure("random"),
            f"{env}: reward over {random['worlds']} random worlds",
        )
        return (
            table(["", "value"], rows, raw_cells=True)
            + share_paragraph(random.get("share", {}), res["metric"])
            + image(figure, f"{env}: distribution of the normalised reward over random worlds (cf. Figure 6a)")
        )

    return per_env(results, "random", render, "random", "no random campaign in the store")


def strategic_section(run_dir: Path, results: dict) -> str:
    def render(env: str, res: dict) -> str:
        extra = highlighted(env)
        rows = []
        for label in ("min", "max"):
            found = res[label]
            rows.append(
                [
                    f"<td>{label}imising world, found: the selection's figure ({esc(found['campaign'])}, generation {found['generation']}, "
                    f"slot {found['slot']}; {found['evaluated']} worlds searched)</td>",
                    number(f"{env}.{label}.raw", found["raw"]),
                    number(f"{env}.{label}.normalised", found["normalised"]),
                    *[number(f"{env}.{label}.{name}", found[name]) for name in extra],
                    prior_cell(f"{env}.{label}.latent_norm", found.get("prior")),
                ]
            )
            if "confirmed" in found:
                rows.append([*confirmed_row(env, label, found["confirmed"], extra), "<td>the same world</td>"])
        note = (
            "<p>Found: the world's score on the episodes it was selected on, the best of many noisy scores and so partly luck "
            "(the winner's curse). Confirmed: the same world replayed on fresh episodes from keys no search drew, with the 95% "
            "interval of their mean; the confirmed figure is the world's.</p>"
            if any("confirmed" in res[label] for label in ("min", "max"))
            else "<p>These worlds were not confirmed on fresh episodes (a run from before confirmation): each figure is the "
            "selection's own, partly luck.</p>"
        )
        return (
            table(
                ["world", "reward (raw)", "reward (normalised)", *[n.replace("_", " ") for n in extra], "|z| (under the prior)"], rows, raw_cells=True
            )
            + note
            + PRIOR_NOTE
            + image(
                res["layout"].figure("strategic"),
                f"{env}: the worlds {searcher(res['min'].get('optimiser', 'cmaes'))} found minimising and maximising reward, "
                "against random worlds (cf. Figures 1, 6b)",
            )
        )

    return per_env(results, "strategic", render, "min", "no strategic campaigns in the store")


def searcher(optimiser: str) -> str:
    """Who found a strategic world, in words: "CMA-ES", "Bayesian optimisation", "random search"."""
    return "random search" if optimiser == "random" else OPTIMISER_WORDS.get(optimiser, optimiser or "the search")


PRIOR_NOTE = (
    "<p>|z|: the norm of the world's latent, with its percentile among draws of G's prior N(0, I) (their |z| follows the "
    "χ distribution). Searches stay inside the prior's typical set, |z| at most its 99.9th percentile, unless run with "
    "<code>--prior-bound none</code>; a world far beyond it is one the generator was never trained to make.</p>"
)


def prior_cell(key: str, prior: dict | None) -> str:
    """A found world's |z| with its percentile under the prior (``search.prior.prior_summary``), or "–" without a latent."""
    from worldagent.search.prior import ordinal

    if not prior:
        return "<td>–</td>"
    where = f"{ordinal(100 * prior['percentile'])} pct" if prior["percentile"] <= 0.9999 else f"tail 1e{prior['tail_log10']:.0f}"
    return number(key, prior["norm"], 3, f" ({where})")


def confirmed_row(env: str, label: str, confirmed: dict, extra) -> list[str]:
    """A strategic world's confirmed figures: each the fresh episodes' mean and its 95% interval."""

    def cell(name: str) -> str:
        fresh = confirmed[name]
        return number(f"{env}.{label}.confirmed.{name}", fresh["mean"], 4, f" [{fmt(fresh['low'], 3)}, {fmt(fresh['high'], 3)}]")

    return [
        f"<td>{label}imising world, confirmed: the same world on {confirmed['repeats']} fresh episodes</td>",
        cell("raw"),
        cell("normalised"),
        *[cell(name) for name in extra],
    ]


def confirmed_comparison(env: str, res: dict) -> str:
    """Figure 7 ranked again on confirmed values: each seed's reported world replayed on fresh episodes, the mean over
    seeds with its interval, the episodes spent with confirmation counted, and whether the paper's ordering survives."""
    from worldagent.reports.comparison import confirmed_efficiency, ordering

    confirmed = res["compare"].get("confirmed")
    if not confirmed:
        return missing("the reported worlds were not confirmed on fresh episodes (a run from before confirmation): ranked by found figures only")
    runs, metric = res["compare"]["runs"], res["metric"]
    rows = confirmed_efficiency(runs, confirmed, metric)
    verdict = ordering(rows, confirmed, metric)
    body = []
    for row in sorted(rows, key=lambda row: row["rank"]):
        opt, key = row["optimiser"], f"{env}.compare.{row['optimiser']}"
        interval = f" [{fmt(row['confirmed_mean_low'], 3)}, {fmt(row['confirmed_mean_high'], 3)}]"
        per_seed = zip(row["confirmed"], row["confirmed_low"], row["confirmed_high"])
        seeds = "; ".join(f"{fmt(m, 3)} [{fmt(lo, 3)}, {fmt(hi, 3)}]" for m, lo, hi in per_seed)
        body.append(
            [
                f"<td>{esc(opt)}</td>",
                f"<td class='num'>{row['rank']}</td>",
                number(f"{key}.confirmed_mean", row["confirmed_mean"], 4, interval),
                f"<td>{esc(seeds)}</td>",
                number(f"{key}.found_mean", row["found_mean"]),
                number(f"{key}.episodes", row["episodes"], 6, f" ({row['search_episodes']:,} + {row['confirmation_episodes']:,})"),
            ]
        )
    head = [
        "optimiser",
        "rank (confirmed)",
        f"confirmed {metric} of the reported world (mean over seeds, 95% interval)",
        "per seed: confirmed [95% interval]",
        f"found {metric} (the selection's, mean over seeds)",
        "episodes spent (search + confirmation)",
    ]
    return (
        "<h4>Ranked by confirmed values</h4>"
        + table(head, body, raw_cells=True)
        + f"<p data-field='compare-ordering' data-verdict='{esc(verdict['verdict'])}'>{esc(verdict.get('text', ''))}</p>"
    )


def comparison_section(run_dir: Path, results: dict) -> str:
    from worldagent.reports.comparison import comparison_figure, confirmed_efficiency, sample_efficiency

    def render(env: str, res: dict) -> str:
        outputs = res["phases"]["compare"].get("outputs", {})
        if "skipped" in outputs:
            return missing(f"skipped: {outputs['skipped']}")
        if "compare" not in res:
            return missing("no comparison campaigns in the store")
        runs, random = res["compare"]["runs"], res["random"]["scores"]
        rows = sample_efficiency(runs, random, maximize=False)
        quantiles = [k[len("median_q") :] for k in rows[0] if k.startswith("median_q")]
        body = []
        for row in rows:
            opt = row["optimiser"]
            cells = [f"<td>{esc(opt)}</td>", f"<td class='num'>{row['seeds']}</td>", f"<td class='num'>{row['evaluations']}</td>"]
            for q in quantiles:
                cells.append(number(f"{env}.compare.{opt}.median_q{q}", row[f"median_q{q}"], 4, f" ({row[f'never_q{q}']}/{row['seeds']} never)"))
            cells += [number(f"{env}.compare.{opt}.best_mean", row["best_mean"]), number(f"{env}.compare.{opt}.mean_sampled", row["mean_sampled"])]
            body.append(cells)
        head = [
            "optimiser",
            "seeds",
            "worlds/seed",
            *[f"worlds to reach random q{q} (≤ {fmt(rows[0][f'threshold_q{q}'])})" for q in quantiles],
            f"best {res['metric']} (mean over seeds)",
            f"mean {res['metric']} sampled",
        ]
        confirmed = res["compare"].get("confirmed")
        rows = confirmed_efficiency(runs, confirmed, res["metric"]) if confirmed else None
        figure = comparison_figure(runs, random, res["metric"], res["layout"].figure("comparison"), maximize=False, confirmed=rows)
        return (
            table(head, body, raw_cells=True)
            + "<p>Worlds each optimiser evaluated (median over seeds) before its first world scoring at or below the random "
            "distribution's q-quantile; random sampling needs 1/q on average. Best: found, each seed's best score (the "
            "selection's, partly luck).</p>"
            + confirmed_comparison(env, res)
            + image(figure, f"{env}: rewards of the worlds each optimiser sampled while minimising reward, against random worlds (cf. Figure 7)")
        )

    return per_env(results, "compare", render)


def influence_section(run_dir: Path, results: dict) -> str:
    def render(env: str, res: dict) -> str:
        outputs = res["phases"]["influence"].get("outputs", {})
        if "skipped" in outputs:  # e.g. no selected world kept the property on its fresh episodes
            return missing(f"skipped: {outputs['skipped']}")
        if "influence" not in res:
            return missing("no influence.json")
        result = res["influence"]
        worlds = result["worlds"]
        rows = []
        for metric, by_label in result["summary"].items():
            rows.append(
                [f"<td>{esc(metric)}</td>"]
                + [
                    number(f"{env}.influence.{metric}_{label}", by_label[label]["mean"]) + f"<td class='num'>{fmt(by_label[label]['ci95'], 3)}</td>"
                    for label in ("default", "influenced")
                ]
            )
        failed = "".join(
            f"<p class='error' data-flag='failed-training'>Warning: the {esc(name)} agent {esc(why)}; its seed weighs on the means and intervals.</p>"
            for name, why in result.get("failed_training", {}).items()
        )
        seeds = seeds_of(res)
        if seeds == 1:
            failed += (
                "<p class='warning' data-flag='one-seed'>One seed per arm: each mean below is one agent's, and one agent cannot show "
                "which way influencing moves a metric; train more seeds (the paper's preset trains several) before reading a direction.</p>"
            )
        return (
            failed + f"<p>Selection <code>{esc(result['selection']['describe'])}</code>: {worlds['selected']} of {worlds['tried']} candidate worlds "
            f"became the influenced training distribution{confirmed_selection(worlds)}; agents trained with seeds "
            f"{esc(', '.join(map(str, result['config']['seeds'])))}, "
            f"evaluated on {result['config']['eval_worlds']} random worlds x {result['config']['repeats']} episodes.</p>"
            f"<p data-field='influence-regime'>Both arms' training: {esc(training_regime(result))}.</p>"
            + table(["metric", "default training (mean over seeds)", "95% CI ±", "influenced training", "95% CI ±"], rows, raw_cells=True)
            + image(
                res["layout"].figure("influence"),
                f"{env}: default against influenced training, with worlds of the influenced distribution (cf. Figure 8)",
            )
        )

    return per_env(results, "influence", render)


def confirmed_selection(worlds: dict) -> str:
    """ " (those of the 118 selected whose property held on 32 fresh episodes each)", or nothing unconfirmed."""
    confirmation = worlds.get("confirmation")
    if confirmation is None:
        return " (as found: not confirmed on fresh episodes)"
    return f" (those of the {confirmation['selected']} selected whose property held on {confirmation['repeats']} fresh episodes each)"


def atlas_section(run_dir: Path, results: dict) -> str:
    def render(env: str, res: dict) -> str:
        outputs = res["phases"]["atlas"].get("outputs", {})
        if "skipped" in outputs:
            return missing(f"skipped: {outputs['skipped']}")
        if "atlas" not in res:
            return missing("no atlas campaign in the store")
        found = res["atlas"]
        grid, key = found["atlas"].grid, f"{env}.atlas"
        rows = [
            ["<td>worlds evaluated (CMA-ME)</td>" + number(f"{key}.evaluations", found["evaluations"])],
            [f"<td>cells filled of {grid.size} ({' x '.join(map(str, grid.cells))}: {esc(', '.join(grid.descriptors))})</td>"]
            + [number(f"{key}.coverage", found["coverage"], 3, " coverage")],
            ["<td>QD-score, found (the search's scores; offset: the worst world evaluated)</td>" + number(f"{key}.qd_score", found["qd_score"])],
        ]
        body = ""
        if "selection" in found:
            event = esc(found["selection"].describe())
            rows += [
                [f"<td>failing evaluations ({event}, the search's episodes)</td>" + number(f"{key}.failing", found["failing"])],
                ["<td>distinct failing worlds (different after repair)</td>" + number(f"{key}.distinct_failing", found["distinct_failing"])],
            ]
        rows += corrected_rows(key, found.get("confirmed"))
        if "selection" in found:
            body = probability_table(env, found, res["phases"]["atlas"]["config"]) + cluster_table(found) + pair_list(run_dir, outputs)
        return (
            table(["", "value"], rows, raw_cells=True)
            + image(run_dir / outputs["figure"], f"{env}: the worst world of each cell of the descriptor grid, and worlds of distinct cells")
            + body
        )

    return per_env(results, "atlas", render)


def corrected_rows(key: str, confirmed: dict | None) -> list[list[str]]:
    """The corrected archive (every elite replayed on fresh episodes; ``search.corrected_atlas.corrected_summary``) beside the
    found one: QD-score and, with a failure, failing cells and distinct failing worlds."""
    if confirmed is None:
        return [["<td>elites confirmed on fresh episodes</td><td class='num'>no (the figures above are the search's own)</td>"]]
    found, fresh = confirmed["found"], confirmed["confirmed"]
    note = f"{confirmed['elites']} elites, each on {confirmed['repeats']} fresh episodes"
    rows = [[f"<td>QD-score of the corrected archive ({note}; same offset)</td>" + number(f"{key}.confirmed.qd_score", fresh["qd_score"])]]
    if "failing_cells" in fresh:
        rows += [
            ["<td>failing cells, found (the elite's search episodes)</td>" + number(f"{key}.found.failing_cells", found["failing_cells"])],
            [
                "<td>failing cells, confirmed (the elite's confirmed interval beyond the threshold)</td>"
                + number(f"{key}.confirmed.failing_cells", fresh["failing_cells"])
            ],
            ["<td>distinct failing worlds among the elites, found</td>" + number(f"{key}.found.failing_worlds", found["failing_worlds"])],
            ["<td>distinct failing worlds among the elites, confirmed</td>" + number(f"{key}.confirmed.failing_worlds", fresh["failing_worlds"])],
        ]
    return rows


def probability_table(env: str, found: dict, config: dict) -> str:
    """P(failure) for worlds z ~ N(0, I): each estimator's estimate, 95% interval and cost, replayed from the store."""
    names = {"mc": "Monte Carlo (exact binomial interval)", "is": "importance sampling (prior worlds weighted by a surrogate of their descriptors)"}
    rows = []
    for method, estimate in found["estimates"].items():
        if isinstance(estimate, str):
            rows.append([f"<td>{names[method]}</td>", f"<td colspan='6' class='error'>{esc(estimate)}</td>"])
            continue
        key = f"{env}.failure.{method}"
        ess = "" if estimate.ess is None else f"{estimate.ess:.0f} ({estimate.event_ess:.0f} of the hits)"
        rows.append(
            [f"<td>{names[method]}</td>"]
            + [number(f"{key}.{field}", getattr(estimate, field), 3) for field in ("estimate", "low", "high")]
            + [number(f"{key}.{field}", getattr(estimate, field)) for field in ("hits", "worlds", "episodes")]
            + [f"<td class='num'>{ess}</td>"]
        )
    if not rows:
        return missing("no failure-rate estimate (the preset's failure_worlds is 0)")
    return f"<h4>How likely is <code>{esc(found['selection'].describe())}</code> on worlds z ~ N(0, I)?</h4>" + table(
        ["method", "P", "95% low", "95% high", "hits", "worlds", f"episodes ({config.get('repeats', '?')} per world)", "ESS"], rows, raw_cells=True
    )


def cluster_table(found: dict) -> str:
    """The failing worlds' groups: size and mean descriptors."""
    names = found["atlas"].grid.descriptors
    rows = [[str(i + 1), str(len(c.members)), *[fmt(v, 3) for v in c.centre]] for i, c in enumerate(found["clusters"])]
    return "<h4>Failure groups (k-means on descriptors and latents)</h4>" + (
        table(["group", "worlds", *[f"mean {n.replace('_', ' ')}" for n in names]], rows) if rows else missing("no failing world")
    )


def pair_list(run_dir: Path, outputs: dict) -> str:
    """The counterfactual figure: each failing world beside the nearest passing one on its latent segment."""
    if "counterfactuals" not in outputs:
        return ""
    spots = ", ".join(f"{p['t_failing']:.3f}–{p['t_passing']:.3f}" for p in outputs.get("pairs", []))
    caption = f"each failing world beside the nearest passing world on the latent segment toward it (boundary at t = {spots or 'none'})"
    return "<h4>Why: the nearest passing world</h4>" + image(run_dir / outputs["counterfactuals"], caption)


HEADLINE_DIGITS = 3  # significant digits: the paper prints two


def headline_table(rows: list[Headline]) -> str:
    """Ours beside the paper's; a number that departs from it (``departures.differs``) is marked."""
    notes = any(row.note for row in rows)
    body = [
        [
            f"<td>{esc(row.label)}</td>",
            number(row.key, row.ours, HEADLINE_DIGITS),
            f"<td class='num'>{'–' if row.paper is None else fmt(row.paper)}</td>",
            "<td class='differs'>differs</td>" if differs(row.ours, row.paper) else "<td></td>",
            *([f"<td>{esc(row.note)}</td>"] if notes else []),
        ]
        for row in rows
    ]
    return table(["quantity", "ours", "paper", "", *(["note"] if notes else [])], body, raw_cells=True)


def headline_section(rows: list[Headline], run_dir: Path) -> str:
    """The numbers the paper reports first; the others (raw values, numbers it does not give) folded below them."""
    compared = [row for row in rows if row.paper is not None]
    others = [row for row in rows if row.paper is None]
    folded = f"<details><summary>{len(others)} more numbers of this run (the paper gives none)</summary>{headline_table(others)}</details>"
    return (
        headline_table(compared)
        + (folded if others else "")
        + "<p>Ours are recomputed from the run stores when the report is built (n/a: the phase has not run; –: the paper gives no number). "
        "Normalised: by the main metric's rule-given range where the environment has one (racing), otherwise by the run's "
        "best single episode (harvest; see the module docstring of <code>worldagent.reports.results</code>).</p>" + explorer_hint(run_dir)
    )


# -- the report -------------------------------------------------------------------------------


def build_report(run_dir: Path | str) -> Path:
    """Write ``run_dir/report.html`` from the manifest, the stores and the phases' outputs.

    Args:
        run_dir: a run directory written by ``reproduce``.

    Returns:
        The report's path.
    """
    run = Run.open(run_dir)
    run_dir, manifest, envs = run.run_dir, run.manifest, run.require_envs()
    results = {env: env_results(run, env) for env in envs}
    bodies = {
        "provenance": overview(manifest, run_dir),
        "generator": generator_section(run_dir, results),
        "training": training_section(run_dir, results),
        "curriculum": curriculum_section(run, results),
        "random": random_section(run_dir, results),
        "strategic": strategic_section(run_dir, results),
        "comparison": comparison_section(run_dir, results),
        "influence": influence_section(run_dir, results),
        "atlas": atlas_section(run_dir, results),
        "headline": headline_section(headlines(results), run_dir),
        "departures": departures_section(headlines(results), results, manifest.get("preset")),
    }
    nav = "<nav>" + "".join(f'<a href="#{anchor}">{esc(title)}</a>' for anchor, title in SECTIONS) + "</nav>"
    title = f"Reproduction, {manifest.get('preset', '?')} preset ({', '.join(envs)})"
    page = (
        f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>{esc(title)}</title><style>{CSS}</style></head><body>"
        f"<h1>{esc(title)}</h1><p>Optimising Worlds to Evaluate and Influence Reinforcement Learning Agents, reproduced end to end.</p>"
        + nav
        + "".join(section(anchor, heading, bodies[anchor]) for anchor, heading in SECTIONS)
        + "</body></html>\n"
    )
    return write_text(run_dir / REPORT_FILE, page)
