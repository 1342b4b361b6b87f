"""How efficiently each optimiser finds extreme worlds (paper §6.1.3, Figure 7).

The yardstick is the random distribution (Figure 6a): a world "at the q quantile" is one that
random sampling finds with probability q per draw, i.e. after 1/q draws on average (10, 20 and
100 for q = 0.1, 0.05, 0.01). For each optimiser and seed we count the evaluated worlds it took
to first reach a score at or beyond that quantile. A seed that never reaches it is reported as
such — never as a made-up number — and the median over seeds counts it as "later than any
budget", so the median itself is "not reached" when half the seeds or more never got there.

``runs`` everywhere is ``{optimiser: [f[n] scores in evaluation order, one array per seed]}``,
as ``search.experiments.compare_optimisers`` returns it.

A seed's best world is the best of many noisy scores, partly luck (the winner's curse), so the
optimisers are also ranked by the *confirmed* value of the world each seed reports
(``experiments.confirm_optimisers``: ``{optimiser: [analysis.confirm.ConfirmedWorld per seed]}``),
over seeds, with intervals, at the episodes each spent with its confirmation counted
(``confirmed_efficiency``); ``ordering`` says in words whether the paper's ordering (ES finds more
extreme worlds than BO, which beats random; §6.1.3) survives on confirmed values, or that the intervals
cannot tell.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from worldagent.errors import WorldagentError
from worldagent.files import write_atomically, write_text

QUANTILES = (0.1, 0.05, 0.01)
PAPER_ORDER = ("cmaes", "bo", "random")  # §6.1.3: ES finds lower reward than BO, which beats random search
CONFIDENCE = 0.95


def thresholds(random_scores: np.ndarray, quantiles: Sequence[float], maximize: bool) -> dict[float, float]:
    """The score of each tail quantile of the random distribution (upper tail when maximising)."""
    scores = _finite(random_scores, "random scores")
    for q in quantiles:
        if not 0.0 < q < 1.0:
            raise WorldagentError(f"quantile {q}; pass tail fractions strictly between 0 and 1 (e.g. 0.05).")
    return {q: float(np.quantile(scores, 1.0 - q if maximize else q)) for q in quantiles}


def evaluations_to_reach(scores: np.ndarray, threshold: float, maximize: bool) -> int | None:
    """1-based number of the first evaluation at or beyond ``threshold``; None if none is."""
    scores = np.asarray(scores, np.float64)
    hit = scores >= threshold if maximize else scores <= threshold  # NaN never counts as a hit
    return int(np.argmax(hit)) + 1 if hit.any() else None


def censored_median(counts: Sequence[int | None]) -> float | None:
    """Median of counts where None means "not within the budget" (+inf); None if the median is."""
    values = np.array([np.inf if c is None else c for c in counts], np.float64)
    median = float(np.median(values))
    return median if np.isfinite(median) else None


def best_so_far(scores: np.ndarray, maximize: bool) -> np.ndarray:
    """f[n]: the best score among the first i + 1 evaluations (NaN scores ignored)."""
    scores = np.asarray(scores, np.float64)
    filled = np.where(np.isfinite(scores), scores, -np.inf if maximize else np.inf)
    return np.maximum.accumulate(filled) if maximize else np.minimum.accumulate(filled)


def sample_efficiency(
    runs: dict[str, list[np.ndarray]], random_scores: np.ndarray, quantiles: Sequence[float] = QUANTILES, maximize: bool = False
) -> list[dict]:
    """One row per optimiser: evaluations to reach the random distribution's tail quantiles.

    Args:
        runs: {optimiser: per-seed f[n] scores in evaluation order}.
        random_scores: f[m] the metric on random worlds (the reference distribution).
        quantiles: tail fractions q; the target is the random q-quantile (1 - q when maximising).
        maximize: the direction the optimisers pushed.

    Returns:
        A list of dicts with: ``optimiser``; ``seeds``; ``evaluations`` (worlds per seed, the
        smallest if they differ); ``best_mean`` / ``best_sd`` (the best score of each seed: mean and
        sample standard deviation, NaN for one seed); ``mean_sampled`` (mean over all sampled
        worlds); and per quantile q: ``threshold_q{q}`` (the target score), ``reach_q{q}`` (per seed,
        evaluations to reach it or None), ``median_q{q}`` (``censored_median`` of those) and
        ``never_q{q}`` (seeds that did not reach it).
    """
    if not runs:
        raise WorldagentError("no optimiser runs to compare; run compare_optimisers first.")
    targets = thresholds(random_scores, quantiles, maximize)
    rows = []
    for name, seeds in runs.items():
        if not seeds or any(len(s) == 0 for s in seeds):
            raise WorldagentError(f"optimiser {name!r} has a seed without evaluations; run its campaigns first.")
        bests = np.array([best_so_far(s, maximize)[-1] for s in seeds])
        pooled = np.concatenate([np.asarray(s, np.float64) for s in seeds])
        row = {
            "optimiser": name,
            "seeds": len(seeds),
            "evaluations": min(len(s) for s in seeds),
            "best_mean": float(np.mean(bests)),
            "best_sd": float(np.std(bests, ddof=1)) if len(bests) > 1 else float("nan"),
            "mean_sampled": float(np.nanmean(pooled)),
        }
        for q, threshold in targets.items():
            reach = [evaluations_to_reach(s, threshold, maximize) for s in seeds]
            row[f"threshold_q{q:g}"] = threshold
            row[f"reach_q{q:g}"] = reach
            row[f"median_q{q:g}"] = censored_median(reach)
            row[f"never_q{q:g}"] = sum(r is None for r in reach)
        rows.append(row)
    return rows


def _quantiles_of(rows: list[dict]) -> list[str]:
    """The quantile labels ("0.1", ...) the rows were computed for, in order."""
    return [key[len("median_q") :] for key in rows[0] if key.startswith("median_q")] if rows else []


def _reach_cell(row: dict, q: str) -> str:
    """ "12 (1 never)" — the median count and how many seeds never reached the target."""
    median, never, seeds = row[f"median_q{q}"], row[f"never_q{q}"], row["seeds"]
    text = "not reached" if median is None else f"{median:g}"
    return f"{text} ({never}/{seeds} never)" if never else text


def comparison_table_markdown(rows: list[dict], metric: str = "score", maximize: bool = False) -> str:
    """A Markdown table of ``sample_efficiency`` rows, with a note on how to read it."""
    if not rows:
        raise WorldagentError("no rows to tabulate; compute sample_efficiency first.")
    labels = _quantiles_of(rows)
    sign = "≥" if maximize else "≤"
    head = [
        "optimiser",
        "seeds",
        "worlds/seed",
        *[f"worlds to {sign} q{q} ({rows[0][f'threshold_q{q}']:.4g})" for q in labels],
        f"best {metric} (mean ± sd)",
        f"mean {metric} sampled",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    for row in rows:
        sd = "" if np.isnan(row["best_sd"]) else f" ± {row['best_sd']:.3g}"
        cells = [
            row["optimiser"],
            str(row["seeds"]),
            str(row["evaluations"]),
            *[_reach_cell(row, q) for q in labels],
            f"{row['best_mean']:.4g}{sd}",
            f"{row['mean_sampled']:.4g}",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    tail = "lower" if not maximize else "upper"
    expected = ", ".join(f"q{q}: {1 / float(q):g}" for q in labels)
    lines.append("")
    lines.append(
        f"Worlds to reach the {tail} q-quantile of the random distribution: median over seeds of the evaluations "
        f"until the first world scoring {sign} that value ('never': seeds that did not within their budget). "
        f"Random sampling needs 1/q worlds on average ({expected})."
    )
    return "\n".join(lines) + "\n"


def comparison_csv(rows: list[dict]) -> str:
    """The rows as CSV; per-seed counts joined by ';' with "never" for a seed that did not reach."""
    import csv

    if not rows:
        raise WorldagentError("no rows to write; compute sample_efficiency first.")
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]))
    writer.writeheader()
    for row in rows:
        cells = {}
        for key, value in row.items():
            if isinstance(value, list):
                value = ";".join("never" if v is None else str(v) for v in value)
            cells[key] = "not reached" if value is None else value
        writer.writerow(cells)
    return buffer.getvalue()


def write_comparison(
    rows: list[dict],
    out_dir: Path | str,
    metric: str = "score",
    maximize: bool = False,
    confirmed: list[dict] | None = None,
    order: dict | None = None,
) -> tuple[Path, ...]:
    """Write ``comparison.md`` and ``comparison.csv`` into ``out_dir`` (atomically); with ``confirmed`` rows
    (``confirmed_efficiency``) and their ``ordering``, the confirmed table beside the found one in the
    Markdown, ``comparison-confirmed.csv`` and ``comparison.json`` (both tables and the verdict) too."""
    import json

    out_dir = Path(out_dir)
    markdown = comparison_table_markdown(rows, metric, maximize)
    if confirmed:
        markdown += "\n" + confirmed_table_markdown(confirmed, order or {}, metric, maximize)
    paths = (write_text(out_dir / "comparison.md", markdown), write_text(out_dir / "comparison.csv", comparison_csv(rows)))
    if not confirmed:
        return paths
    from worldagent.influence.statistics import json_safe

    document = json_safe({"metric": metric, "maximize": maximize, "found": rows, "confirmed": confirmed, "ordering": order or {}})
    return (
        *paths,
        write_text(out_dir / "comparison-confirmed.csv", comparison_csv(confirmed)),
        write_text(out_dir / "comparison.json", json.dumps(document, indent=2, default=_json_value) + "\n"),
    )


def _json_value(value):
    """JSON for numpy numbers (NaN as null)."""
    value = float(value)
    return value if np.isfinite(value) else None


# -- ranked by confirmed values (issue 50) --------------------------------------------------------


def seed_interval(values: Sequence[float], confidence: float = CONFIDENCE) -> tuple[float, float, float]:
    """(mean, low, high): the mean of per-seed values and its Student's t interval over seeds (NaN bounds for one seed)."""
    from scipy import stats

    values = np.asarray(values, np.float64)
    mean = float(values.mean())
    if len(values) < 2:
        return mean, float("nan"), float("nan")
    half = float(stats.t.ppf(1 - (1 - confidence) / 2, len(values) - 1) * values.std(ddof=1) / np.sqrt(len(values)))
    return mean, mean - half, mean + half


def welch_difference(a: Sequence[float], b: Sequence[float], confidence: float = CONFIDENCE) -> tuple[float, float, float]:
    """(mean(a) − mean(b), low, high): Welch's interval of a difference of means (each side needs two values)."""
    from scipy import stats

    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    difference = float(a.mean() - b.mean())
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    se = float(np.sqrt(va + vb))
    if se == 0:
        return difference, difference, difference
    df = (va + vb) ** 2 / (va**2 / (len(a) - 1) + vb**2 / (len(b) - 1))
    half = float(stats.t.ppf(1 - (1 - confidence) / 2, df) * se)
    return difference, difference - half, difference + half


def _confirmed_means(worlds: Sequence, metric: str) -> np.ndarray:
    return np.array([c.confirmed(metric).mean for c in worlds], np.float64)


def confirmed_efficiency(runs: dict[str, list[np.ndarray]], confirmed: dict[str, list], metric: str, maximize: bool = False) -> list[dict]:
    """One row per optimiser: the confirmed value of the world each seed reports, over seeds, and the episodes spent.

    Args:
        runs: {optimiser: per-seed f[n] scores within the budget} (``compare_optimisers``).
        confirmed: {optimiser: [``ConfirmedWorld`` per seed, in ``runs``' seed order]} (``confirm_optimisers``).
        metric: the compared metric; maximize: the direction the optimisers pushed.

    Returns:
        Dicts with ``optimiser``; ``seeds``; ``found`` / ``confirmed`` (per seed: the reported world's found
        figure, the selection's, and its confirmed mean), ``confirmed_low`` / ``confirmed_high`` (per seed: the
        world's 95% interval over its fresh episodes); ``found_mean``; ``confirmed_mean`` with
        ``confirmed_mean_low`` / ``confirmed_mean_high`` (a t interval over seeds; with one seed, that world's
        interval over episodes: ``interval_over`` says which); ``search_episodes``, ``confirmation_episodes``
        and ``episodes`` (their sum, over seeds: the equal budget with confirmation counted); ``rank`` and
        ``found_rank`` (1: the most extreme in the search's direction, by confirmed and by found means).
    """
    missing = [name for name in runs if len(confirmed.get(name, ())) != len(runs[name])]
    if missing:
        raise WorldagentError(f"optimiser {missing[0]!r} has no confirmed world for every seed; run confirm_optimisers first.")
    rows = []
    for name, seeds in runs.items():
        worlds = confirmed[name]
        means = _confirmed_means(worlds, metric)
        intervals = [c.confirmed(metric) for c in worlds]
        mean, low, high = seed_interval(means)
        over = "seeds"
        if len(worlds) == 1:
            mean, low, high, over = intervals[0].mean, intervals[0].low, intervals[0].high, "episodes"
        searched = int(sum(len(s) * len(c.selected.episodes) for s, c in zip(seeds, worlds)))
        confirmation = int(sum(c.repeats for c in worlds))
        found = [float(c.found(metric).mean) for c in worlds]
        rows.append(
            {
                "optimiser": name,
                "seeds": len(worlds),
                "found": found,
                "confirmed": [float(v) for v in means],
                "confirmed_low": [float(i.low) for i in intervals],
                "confirmed_high": [float(i.high) for i in intervals],
                "confirmation_repeats": [c.repeats for c in worlds],
                "found_mean": float(np.mean(found)),
                "confirmed_mean": float(mean),
                "confirmed_mean_low": float(low),
                "confirmed_mean_high": float(high),
                "interval_over": over,
                "search_episodes": searched,
                "confirmation_episodes": confirmation,
                "episodes": searched + confirmation,
            }
        )
    for key, rank in (("confirmed_mean", "rank"), ("found_mean", "found_rank")):
        extreme = [-row[key] if maximize else row[key] for row in rows]
        for row, value in zip(rows, extreme):
            row[rank] = 1 + sum(other < value for other in extreme)  # ties share a place
    return rows


def _pair_difference(better: Sequence, worse: Sequence, metric: str, maximize: bool) -> dict:
    """How far ``worse``'s confirmed worlds sit from ``better``'s, signed so that > 0 agrees with the paper
    (over seeds when both have two; else over the pooled fresh episodes of their worlds)."""
    from worldagent.analysis.confirm import metric_values

    sign = -1.0 if maximize else 1.0
    if len(better) > 1 and len(worse) > 1:
        a, b, over = _confirmed_means(worse, metric), _confirmed_means(better, metric), "seeds"
    else:
        pooled = lambda worlds: np.concatenate([metric_values(c.episodes, metric) for c in worlds])  # noqa: E731
        a, b, over = pooled(worse), pooled(better), "episodes"
        a, b = a[np.isfinite(a)], b[np.isfinite(b)]
    difference, low, high = welch_difference(sign * a, sign * b)
    verdict = "holds" if low > 0 else "reversed" if high < 0 else "cannot tell"
    return {"mean": difference, "low": low, "high": high, "over": over, "verdict": verdict}


def ordering(confirmed_rows: list[dict], confirmed: dict[str, list], metric: str, maximize: bool = False, order: Sequence[str] = PAPER_ORDER) -> dict:
    """Whether the paper's ordering (``order``: most extreme first) survives on confirmed values, in words.

    Each neighbouring pair of ``order`` (among the optimisers compared) is tested by the interval of the
    difference between their confirmed values: "holds" when it excludes 0 the paper's way, "reversed" when it
    excludes 0 the other way, "cannot tell" otherwise. The ordering "survives" when every pair holds, is
    "contradicted" when a pair is reversed, and otherwise the intervals cannot tell.

    Returns:
        {"paper": [names], "pairs": [{"better", "worse", "mean", "low", "high", "over", "verdict"}], "verdict":
        "survives" | "contradicted" | "cannot tell" | "n/a", "confirmed_order": [names by confirmed mean],
        "found_order": [names by found mean], "text": the sentence}.
    """
    by_name = {row["optimiser"]: row for row in confirmed_rows}
    paper = [name for name in order if name in by_name]
    ranked = lambda key: [row["optimiser"] for row in sorted(confirmed_rows, key=lambda row: row[key])]  # noqa: E731  (stable: ties keep their order)
    confirmed_order, found_order = ranked("rank"), ranked("found_rank")
    result: dict = {"paper": paper, "pairs": [], "confirmed_order": confirmed_order, "found_order": found_order}
    if len(paper) < 2:
        return result | {"verdict": "n/a", "text": f"fewer than two of {', '.join(order)} were compared: the paper's ordering is not tested."}
    for better, worse in zip(paper, paper[1:]):
        result["pairs"].append({"better": better, "worse": worse, **_pair_difference(confirmed[better], confirmed[worse], metric, maximize)})
    verdicts = [pair["verdict"] for pair in result["pairs"]]
    result["verdict"] = "survives" if all(v == "holds" for v in verdicts) else "contradicted" if "reversed" in verdicts else "cannot tell"
    if min(by_name[name]["seeds"] for name in paper) < 2:  # one seed compares the reported worlds, not the optimisers
        result["verdict"] = "cannot tell"
    result["text"] = _ordering_text(result, by_name, metric, maximize)
    return result


def _ordering_text(result: dict, by_name: dict, metric: str, maximize: bool) -> str:
    """The verdict as sentences: the paper's claim, each pair's difference with its interval, both orders."""
    word = "above" if maximize else "below"
    claim = f" {word} ".join(result["paper"])
    row = next(iter(by_name.values()))
    repeats = sorted(set(r for row in by_name.values() for r in row["confirmation_repeats"]))
    basis = (
        f"confirmed values ({'/'.join(map(str, repeats))} fresh episodes per reported world, {row['seeds']} seed{'s' if row['seeds'] != 1 else ''})"
    )
    pairs = "; ".join(
        f"{p['worse']} − {p['better']} {'(sign flipped: maximising) ' if maximize else ''}{p['mean']:.4g} [{p['low']:.4g}, {p['high']:.4g}] "
        f"over {p['over']}: {p['verdict']}"
        for p in result["pairs"]
    )
    head = {
        "survives": f"On {basis} the paper's ordering ({claim}) survives",
        "contradicted": f"On {basis} the paper's ordering ({claim}) does not survive: a pair is reversed beyond its interval",
        "cannot tell": f"On {basis} the intervals cannot tell whether the paper's ordering ({claim}) holds",
    }[result["verdict"]]
    if any(pair["over"] == "episodes" for pair in result["pairs"]):
        head += " (with one seed the intervals compare the reported worlds, not the optimisers)"
    orders = lambda names, key: ", ".join(f"{n} {by_name[n][key]:.4g}" for n in names)  # noqa: E731
    return (
        f"{head}: {pairs}. Confirmed means rank them {orders(result['confirmed_order'], 'confirmed_mean')}; "
        f"the found figures (the selections', biased by the pick) ranked them {orders(result['found_order'], 'found_mean')}."
    )


def confirmed_table_markdown(rows: list[dict], order: dict, metric: str = "score", maximize: bool = False) -> str:
    """A Markdown table of ``confirmed_efficiency`` rows and the ``ordering`` verdict beneath it."""
    if not rows:
        raise WorldagentError("no confirmed rows to tabulate; run confirm_optimisers first.")
    head = [
        "optimiser",
        "rank (confirmed)",
        f"confirmed {metric} of the reported world (mean over seeds, 95% interval)",
        "per seed: confirmed [95% interval]",
        f"found {metric} (the selection's, mean over seeds)",
        "rank (found)",
        "episodes: search + confirmation = total",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    for row in sorted(rows, key=lambda r: r["rank"]):
        interval = "" if not np.isfinite(row["confirmed_mean_low"]) else f" [{row['confirmed_mean_low']:.4g}, {row['confirmed_mean_high']:.4g}]"
        over = " (one seed: over its episodes)" if row["interval_over"] == "episodes" else ""
        seeds = "; ".join(f"{m:.4g} [{lo:.4g}, {hi:.4g}]" for m, lo, hi in zip(row["confirmed"], row["confirmed_low"], row["confirmed_high"]))
        cells = [
            row["optimiser"],
            str(row["rank"]),
            f"{row['confirmed_mean']:.4g}{interval}{over}",
            seeds,
            f"{row['found_mean']:.4g}",
            str(row["found_rank"]),
            f"{row['search_episodes']:,} + {row['confirmation_episodes']:,} = {row['episodes']:,}",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", order.get("text", ""), ""]
    return "\n".join(lines)


def tail_fraction(values: np.ndarray, random_scores: np.ndarray, maximize: bool) -> np.ndarray:
    """Share of random worlds scoring at or beyond each value: where it sits in the random tail.

    0.01 means only 1% of random worlds are as extreme; 0 means none is (beyond every random world).
    """
    ordered = np.sort(np.asarray(random_scores, np.float64))
    values = np.asarray(values, np.float64)
    if maximize:
        return (len(ordered) - np.searchsorted(ordered, values, side="left")) / len(ordered)
    return np.searchsorted(ordered, values, side="right") / len(ordered)


def _histogram_range(samples: list[np.ndarray]) -> tuple[float, float]:
    """The x-range of the distribution panel: everything, unless a few far outliers would squash
    the bulk into a couple of bins; then the central range (outliers are counted in a note)."""
    everything = np.concatenate(samples)
    low, high = everything.min(), everything.max()
    bulk_low, bulk_high = np.quantile(everything, [0.01, 0.99])
    if (bulk_high - bulk_low) >= 0.2 * (high - low):
        return float(low), float(high)
    pad = 0.25 * max(bulk_high - bulk_low, 1e-9)
    return float(max(low, bulk_low - pad)), float(min(high, bulk_high + pad))


def _distribution_panel(axis, pooled: dict[str, np.ndarray], random_scores: np.ndarray, metric: str, maximize: bool, colours, bins: int) -> None:
    """Figure 7: scores of the worlds each optimiser sampled vs random worlds (density)."""
    low, high = _histogram_range([random_scores, *pooled.values()])
    edges = np.linspace(low, high, bins + 1)
    outside = {"random worlds": random_scores, **pooled}
    notes = []
    for label, values in outside.items():
        below, above = int(np.sum(values < low)), int(np.sum(values > high))
        if below or above:
            notes.append(f"{label}: {below} below {low:.3g}" + (f", {above} above {high:.3g}" if above else ""))
    inside = lambda v: v[(v >= low) & (v <= high)]  # noqa: E731
    axis.hist(
        inside(random_scores),
        bins=edges,
        weights=np.full(len(inside(random_scores)), 1 / len(random_scores)),
        color="0.55",
        alpha=0.6,
        label=f"random worlds (n={len(random_scores)}, mean {random_scores.mean():.3g})",
    )
    for i, (name, values) in enumerate(pooled.items()):
        axis.hist(
            inside(values),
            bins=edges,
            weights=np.full(len(inside(values)), 1 / len(values)),
            histtype="step",
            linewidth=2,
            color=colours(i),
            label=f"{name} (n={len(values)}, mean {values.mean():.3g})",
        )
    axis.set_xlim(low, high)
    axis.set_xlabel(metric)
    axis.set_ylabel("share of the worlds")
    axis.set_title(f"worlds sampled while {'maximising' if maximize else 'minimising'} {metric}")
    axis.legend(fontsize=8, loc="upper right" if not maximize else "upper left")
    if notes:
        axis.text(
            0.02 if not maximize else 0.98,
            0.97,
            "beyond the axis:\n" + "\n".join(notes),
            transform=axis.transAxes,
            fontsize=7,
            va="top",
            ha="left" if not maximize else "right",
            bbox={"facecolor": "white", "alpha": 0.85, "edgecolor": "0.7"},
        )


def _best_so_far_panel(
    axis, runs: dict[str, list[np.ndarray]], random_scores: np.ndarray, metric: str, maximize: bool, colours, confirmed: list[dict] | None = None
) -> None:
    """Best world so far vs evaluations, as its place in the random tail (log scale).

    A tail share is the best-so-far score on the scale of the random distribution, which makes
    one axis for outliers and the bulk; the right axis gives the score at each tick. The dotted
    curve is random search's expectation, 1/(n+1) after n worlds. ``confirmed`` (``confirmed_efficiency``'s
    rows): each optimiser's reported worlds replayed on fresh episodes, drawn past the curves' end as the
    mean over seeds with its 95% interval, where the found curve ends being partly luck.
    """
    count = len(random_scores)
    floor = 0.5 / count  # "beyond every random world"
    longest = 1
    for i, (name, seeds) in enumerate(runs.items()):
        length = min(len(s) for s in seeds)
        longest = max(longest, length)
        curves = np.stack([np.maximum(tail_fraction(best_so_far(s, maximize)[:length], random_scores, maximize), floor) for s in seeds])
        x = np.arange(1, length + 1)
        axis.step(x, np.median(curves, axis=0), where="post", color=colours(i), linewidth=2, label=f"{name} (median of {len(seeds)} seeds)")
        axis.fill_between(x, curves.min(axis=0), curves.max(axis=0), step="post", color=colours(i), alpha=0.15, linewidth=0)
    for i, row in enumerate(confirmed or ()):
        index = list(runs).index(row["optimiser"])
        share = lambda v: max(float(tail_fraction(np.array([v]), random_scores, maximize)[0]), floor)  # noqa: E731
        mean, low, high = share(row["confirmed_mean"]), share(row["confirmed_mean_low"]), share(row["confirmed_mean_high"])
        low, high = min(low, high), max(low, high)  # a maximising search's shares fall as values rise
        axis.errorbar(
            [longest * (1.04 + 0.03 * i)],
            [mean],
            yerr=[[mean - low], [high - mean]],
            fmt="D",
            color=colours(index),
            capsize=3,
            label="confirmed on fresh episodes (mean over seeds, 95%)" if i == 0 else None,
        )
    x = np.arange(1, longest + 1)
    axis.plot(x, 1 / (x + 1), color="0.3", linestyle=":", linewidth=1.2, label="random search, expected 1/(n+1)")
    axis.axhline(floor, color="0.5", linewidth=0.8)
    axis.set_yscale("log")
    axis.set_ylim(floor / 1.5, 1.05)
    axis.set_xlabel("evaluated worlds")
    axis.set_ylabel(f"share of random worlds {'≥' if maximize else '≤'} best so far")
    axis.set_title(f"best world found vs evaluations (grey line: beyond all {count} random worlds)", fontsize=10)
    ticks = [t for t in (0.5, 0.1, 0.01, 0.001) if t >= 1 / count]
    axis.set_yticks(ticks)
    axis.set_yticklabels([f"{t:g}" for t in ticks])
    axis.minorticks_off()
    scores = axis.twinx()
    scores.set_yscale("log")
    scores.set_ylim(axis.get_ylim())
    scores.set_yticks(ticks)
    scores.set_yticklabels([f"{np.quantile(random_scores, 1 - t if maximize else t):.4g}" for t in ticks])
    scores.minorticks_off()
    scores.set_ylabel(f"{metric} at that share of random worlds")
    axis.legend(fontsize=8, loc="upper right")


def comparison_figure(
    runs: dict[str, list[np.ndarray]],
    random_scores: np.ndarray,
    metric: str,
    out: Path | str,
    maximize: bool = False,
    bins: int = 40,
    confirmed: list[dict] | None = None,
) -> Path:
    """Figure 7 and a best-so-far curve, side by side, to PNG.

    Left: the distribution of the scores of every world each optimiser sampled (all seeds
    pooled) against the random distribution, each as a share of its worlds (far outliers are
    counted in a note rather than squashing the bulk). Right: the best world found so far
    against the number of evaluated worlds, median over seeds with the min–max band, placed in
    the random distribution's tail, with each optimiser's reported worlds as confirmed on fresh
    episodes when ``confirmed`` (``confirmed_efficiency``'s rows) is given (see ``_best_so_far_panel``).
    """
    from worldagent.reports.figures import _pyplot

    if not runs:
        raise WorldagentError("no optimiser runs to draw; run compare_optimisers first.")
    plt = _pyplot()
    random_scores = _finite(random_scores, "random scores")
    colours = plt.get_cmap("tab10")
    pooled = {name: _finite(np.concatenate([np.asarray(s, np.float64) for s in seeds]), f"{name}'s scores") for name, seeds in runs.items()}
    figure, (left, right) = plt.subplots(1, 2, figsize=(13, 4.8), dpi=120)
    _distribution_panel(left, pooled, random_scores, metric, maximize, colours, bins)
    _best_so_far_panel(right, runs, random_scores, metric, maximize, colours, confirmed)
    figure.tight_layout()
    path = write_atomically(out, lambda tmp: figure.savefig(tmp, format="png"))
    plt.close(figure)
    return path


def _finite(values: np.ndarray, what: str) -> np.ndarray:
    """The finite entries of ``values``; an error naming ``what`` if there are none."""
    values = np.asarray(values, np.float64).ravel()
    values = values[np.isfinite(values)]
    if len(values) == 0:
        raise WorldagentError(f"{what} hold no finite value; evaluate some random worlds first.")
    return values
