"""The HTML report of a ``reproduce`` run: one self-contained file, opens offline.

``build_report(run_dir)`` reads ``manifest.json``, each environment's run store, the
generator's ``quality.json``, the agents' learning curves and ``influence.json``, and writes
``run_dir/report.html``: inline CSS, every figure a base64 PNG. The headline numbers are
recomputed from the store (never copied from a phase's log), each printed next to the paper's
value, and each carries ``data-key`` / ``data-value`` attributes so tests and scripts can read
them back exactly. Figures that are pure functions of the store (Figures 6a and 7) are redrawn
here; those that replay agents (Figures 1/6b and 8) were drawn by their phase and are embedded.
A phase that has not run (or failed) shows as such; the report is built from whatever is there.

Normalisation (paper §6: "we normalise all reported metrics to be between 0 and 1"): racing
uses the return's rule-given range (``agents.metrics.normalised_return``); harvest, which has
no such range, divides group reward by the largest single-episode group reward among all the
run's evaluated harvest worlds (so the best episode scores 1; a world's mean stays below).
"""

from __future__ import annotations

import base64
import html
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from worldagent.errors import WorldagentError
from worldagent.files import write_text

REPORT_FILE = "report.html"
SECTIONS = (
    ("overview", "Overview"),
    ("generator", "Generator quality"),
    ("training", "Training curves"),
    ("random", "Random evaluation (Figure 6a)"),
    ("strategic", "Strategic evaluation (Figures 1, 6b)"),
    ("comparison", "Optimiser comparison (Figure 7)"),
    ("influence", "Influencing (Figure 8)"),
    ("headline", "Headline numbers"),
)
ENVS = ("racing", "harvest")


@dataclass(frozen=True)
class Headline:
    """One headline number: ours (from the store) beside the paper's."""

    key: str
    label: str
    ours: float | None
    paper: float | None
    note: str = ""


# -- numbers from the store -------------------------------------------------------------------


def world_means(evaluations, metric: str) -> np.ndarray:
    """f64[worlds]: each evaluated world's mean of ``metric`` over its episodes."""
    return np.array([np.nanmean([np.nan if e.get(metric) is None else float(e[metric]) for e in ev.episodes]) for ev in evaluations], np.float64)


def harvest_scale(store) -> float:
    """The largest single-episode group reward among the store's evaluations (harvest's 1.0)."""
    best = max((float(e["group_reward"]) for ev in store.iter_evaluations() for e in ev.episodes if e.get("group_reward") is not None), default=0.0)
    return best if best > 0 else 1.0


def normalised_means(env: str, evaluations, scale: float) -> np.ndarray:
    """Per-world normalised reward: racing's ``normalised_return``; harvest's group reward / ``scale``."""
    if env == "racing":
        return world_means(evaluations, "normalised_return")
    return world_means(evaluations, "group_reward") / scale


def best_evaluation(evaluations, maximize: bool):
    """The lowest- (or highest-) scoring evaluation; the earliest on ties."""
    finite = [e for e in evaluations if np.isfinite(e.score)]
    if not finite:
        return None
    scores = np.array([e.score for e in finite])
    return finite[int(np.argmax(scores) if maximize else np.argmin(scores))]


def world_summary(env: str, evaluation, scale: float) -> dict:
    """Raw score, normalised score and (racing) crash rate of one evaluated world."""
    summary = {
        "raw": float(evaluation.score),
        "normalised": float(normalised_means(env, [evaluation], scale)[0]),
        "campaign": evaluation.campaign,
        "generation": evaluation.generation,
        "slot": evaluation.slot,
    }
    if env == "racing":
        summary["crash_rate"] = float(world_means([evaluation], "crashed")[0])
    else:
        summary.update(conflict=float(world_means([evaluation], "conflict")[0]), equality=float(world_means([evaluation], "equality")[0]))
    return summary


def env_results(run_dir: Path, env: str, manifest: dict) -> dict:
    """Everything the report shows about one environment, recomputed from the run store."""
    from worldagent.store import RunStore

    phases = manifest.get("phases", {})
    done = {name: phases.get(f"{env}/{name}", {}) for name in ("dataset", "generator", "agent", "random", "strategic", "compare", "influence")}
    results: dict[str, Any] = {"phases": done, "metric": "return" if env == "racing" else "group_reward"}
    store_path = run_dir / env / "store.sqlite"
    if store_path.exists():
        with RunStore(store_path, create=False) as store:
            results.update(store_results(env, store, done))
    influence_path = run_dir / env / "influence" / "influence.json"
    if done["influence"].get("status") == "done" and influence_path.is_file():
        results["influence"] = json.loads(influence_path.read_text())
    quality_path = run_dir / env / "generator" / "quality.json"
    if quality_path.is_file():
        results["quality"] = json.loads(quality_path.read_text())
    return results


def store_results(env: str, store, done: dict) -> dict:
    """Random, strategic and comparison numbers of one environment's store."""
    out: dict[str, Any] = {"scale": harvest_scale(store) if env == "harvest" else None}
    scale = out["scale"] or 1.0
    if done["random"].get("status") == "done":
        evaluations = store.evaluations(done["random"]["outputs"]["campaign"])
        normalised = normalised_means(env, evaluations, scale)
        random = {
            "campaign": done["random"]["outputs"]["campaign"],
            "worlds": len(evaluations),
            "scores": np.array([e.score for e in evaluations]),
            "normalised": normalised,
            "mean_raw": float(np.nanmean([e.score for e in evaluations])),
            "mean_normalised": float(np.nanmean(normalised)),
        }
        if env == "racing":
            random["crash_rate"] = float(np.nanmean(world_means(evaluations, "crashed")))
        else:
            random.update(
                conflict=float(np.nanmean(world_means(evaluations, "conflict"))), equality=float(np.nanmean(world_means(evaluations, "equality")))
            )
        out["random"] = random
    if done["strategic"].get("status") == "done":
        low_name, high_name = done["strategic"]["outputs"]["campaigns"]
        for label, name, maximize in (("min", low_name, False), ("max", high_name, True)):
            evaluations = store.evaluations(name)
            found = best_evaluation(evaluations, maximize)
            if found is not None:
                out[label] = {**world_summary(env, found, scale), "evaluated": len(evaluations)}
    compare = done["compare"]
    if compare.get("status") == "done" and "campaigns" in compare.get("outputs", {}) and "random" in out:
        config = compare["config"]
        budget = {opt: config.get("bo_budget", config["budget"]) if opt == "bo" else config["budget"] for opt in compare["outputs"]["campaigns"]}
        runs = {
            opt: [np.array([e.score for e in store.evaluations(name)[: budget[opt]]], np.float64) for name in names]
            for opt, names in compare["outputs"]["campaigns"].items()
        }
        out["compare"] = {"runs": runs}
    return out


def headlines(results: dict[str, dict]) -> list[Headline]:
    """The paper's headline numbers (§6.1–§6.2) beside ours, recomputed from the stores."""
    rows: list[Headline] = []
    racing, harvest = results.get("racing", {}), results.get("harvest", {})

    def pick(source: dict, *path):
        for step in path:
            if not isinstance(source, dict) or step not in source:
                return None
            source = source[step]
        return float(source) if source is not None else None

    rows += [
        Headline("racing.random.mean_normalised", "Racing: random worlds, mean reward (normalised)", pick(racing, "random", "mean_normalised"), 0.87),
        Headline("racing.random.mean_raw", "Racing: random worlds, mean return (raw)", pick(racing, "random", "mean_raw"), None),
        Headline(
            "racing.random.crash_rate",
            "Racing: random worlds, crash rate",
            pick(racing, "random", "crash_rate"),
            0.11,
            "paper: default training, Fig. 8a",
        ),
        Headline("racing.min.normalised", "Racing: minimising world, reward (normalised)", pick(racing, "min", "normalised"), 0.13),
        Headline("racing.min.raw", "Racing: minimising world, return (raw)", pick(racing, "min", "raw"), None),
        Headline(
            "racing.min.crash_rate", "Racing: minimising world, crash rate", pick(racing, "min", "crash_rate"), None, "paper: 'consistently crashes'"
        ),
        Headline("racing.max.normalised", "Racing: maximising world, reward (normalised)", pick(racing, "max", "normalised"), 0.99),
        Headline("racing.max.raw", "Racing: maximising world, return (raw)", pick(racing, "max", "raw"), None),
        Headline("racing.max.crash_rate", "Racing: maximising world, crash rate", pick(racing, "max", "crash_rate"), 0.0, "paper: 'never crashes'"),
        Headline(
            "harvest.random.mean_normalised",
            "Harvest: random worlds, mean group reward (normalised)",
            pick(harvest, "random", "mean_normalised"),
            0.61,
        ),
        Headline("harvest.random.mean_raw", "Harvest: random worlds, mean group reward (raw)", pick(harvest, "random", "mean_raw"), None),
        Headline("harvest.min.normalised", "Harvest: minimising world, group reward (normalised)", pick(harvest, "min", "normalised"), 0.05),
        Headline("harvest.min.raw", "Harvest: minimising world, group reward (raw)", pick(harvest, "min", "raw"), None),
        Headline("harvest.max.normalised", "Harvest: maximising world, group reward (normalised)", pick(harvest, "max", "normalised"), 0.92),
        Headline("harvest.max.raw", "Harvest: maximising world, group reward (raw)", pick(harvest, "max", "raw"), None),
    ]
    rows += influence_headlines("racing", racing.get("influence"), (("crashed", "crash rate", 0.11, 0.04),))
    change = None
    if racing.get("influence"):
        summary = racing["influence"]["summary"].get("normalised_return", {})
        before, after = pick(summary, "default", "mean"), pick(summary, "influenced", "mean")
        change = 100.0 * (after - before) / abs(before) if before not in (None, 0.0) and after is not None else None
    rows.append(Headline("racing.influence.reward_change_pct", "Racing influence: reward change, % (normalised)", change, -5.0))
    rows += influence_headlines("harvest", harvest.get("influence"), (("conflict", "conflict", 0.51, 0.05), ("equality", "equality", 0.33, 0.78)))
    return rows


def influence_headlines(env: str, result: dict | None, metrics) -> list[Headline]:
    """Default and influenced means of ``metrics`` (over seeds) from ``influence.json``."""
    rows = []
    for metric, label, paper_default, paper_influenced in metrics:
        summary = (result or {}).get("summary", {}).get(metric, {})
        for which, paper in (("default", paper_default), ("influenced", paper_influenced)):
            value = summary.get(which, {}).get("mean")
            rows.append(
                Headline(
                    f"{env}.influence.{metric}_{which}",
                    f"{env.capitalize()} influence: {label}, {which} training",
                    None if value is None else float(value),
                    paper,
                )
            )
    return rows


# -- HTML pieces --------------------------------------------------------------------------------


CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222;line-height:1.45}
h1{margin-bottom:.2em}h2{border-bottom:2px solid #ddd;padding-bottom:.2em;margin-top:2em}h3{margin-bottom:.3em}
table{border-collapse:collapse;margin:.6em 0 1.2em;font-size:.92em}th,td{border:1px solid #ccc;padding:.25em .6em;text-align:left;vertical-align:top}
th{background:#f3f3f3}td.num{text-align:right;font-variant-numeric:tabular-nums}
img{max-width:100%;border:1px solid #eee;margin:.4em 0}figure{margin:.6em 0 1.4em}figcaption{font-size:.88em;color:#555}
.missing{color:#a66;font-style:italic}.error{color:#b00;font-family:monospace;white-space:pre-wrap}
nav a{margin-right:1em}code,pre{background:#f6f6f6;padding:.1em .3em}pre{padding:.6em;overflow-x:auto;font-size:.85em}
"""


def esc(value: Any) -> str:
    return html.escape(str(value))


def fmt(value: Any, digits: int = 4) -> str:
    """A number as text (``n/a`` for None or NaN); other values as given."""
    if value is None:
        return "n/a"
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (int, np.integer)):
        return f"{int(value):,}"
    if isinstance(value, (float, np.floating)):
        return "n/a" if not np.isfinite(value) else f"{float(value):.{digits}g}"
    return str(value)


def number(key: str, value: float | None, digits: int = 4, suffix: str = "") -> str:
    """A table cell holding a number, machine-readable through ``data-key`` / ``data-value``."""
    data = "nan" if value is None or not np.isfinite(value) else repr(float(value))
    return f'<td class="num" data-key="{esc(key)}" data-value="{data}">{fmt(value, digits)}{esc(suffix)}</td>'


def table(head: list[str], rows: list[list[str]], raw_cells: bool = False) -> str:
    """An HTML table; cells are escaped unless ``raw_cells`` (they are pre-rendered ``<td>`` s)."""
    header = "".join(f"<th>{esc(h)}</th>" for h in head)
    body = "".join("<tr>" + ("".join(row) if raw_cells else "".join(f"<td>{esc(c)}</td>" for c in row)) + "</tr>" for row in rows)
    return f"<table><thead><tr>{header}</tr></thead><tbody>{body}</tbody></table>"


def image(path: Path, caption: str) -> str:
    """A PNG embedded as base64 (the report stays one file), or a note that it is missing."""
    if not path.is_file():
        return missing(f"figure not drawn ({path.name})")
    data = base64.b64encode(path.read_bytes()).decode()
    return f'<figure><img alt="{esc(caption)}" src="data:image/png;base64,{data}"><figcaption>{esc(caption)}</figcaption></figure>'


def missing(text: str) -> str:
    return f'<p class="missing">{esc(text)}</p>'


def phase_state(entry: dict | None) -> str | None:
    """None when the phase is done; otherwise a paragraph saying it is not run, running or failed."""
    if not entry:
        return missing("not run")
    status = entry.get("status")
    if status == "done":
        return None
    if status == "failed":
        return f'<p class="missing">failed:</p><p class="error">{esc(entry.get("error", ""))}</p>'
    return missing(f"not finished ({status}); rerun `worldagent reproduce` to resume it")


def section(anchor: str, title: str, body: str) -> str:
    return f'<section id="{anchor}"><h2>{esc(title)}</h2>\n{body}\n</section>'


# -- sections -------------------------------------------------------------------------------


def overview(manifest: dict, run_dir: Path) -> str:
    """Preset, seeds, versions, device, and each phase's status and wall time."""
    rows = [
        ["preset", manifest.get("preset", "?")],
        ["seed", manifest.get("seed", "?")],
        ["environments", ", ".join(manifest.get("envs", []))],
        ["device", manifest.get("device", "?")],
        ["run directory", str(run_dir)],
    ]
    rows += [[f"version: {name}", version] for name, version in manifest.get("versions", {}).items()]
    entries = {key: entry for key, entry in manifest.get("phases", {}).items() if key != "report"}  # this report is being built
    phases = [
        [
            key,
            entry.get("status", "?"),
            fmt(entry.get("wall_s")),
            _time(entry.get("started")),
            _time(entry.get("finished")),
            json.dumps(entry.get("config", {}), sort_keys=True),
            entry.get("error") or entry.get("outputs", {}).get("summary", ""),
        ]
        for key, entry in entries.items()
    ]
    total = sum(entry.get("wall_s") or 0.0 for entry in entries.values())
    return (
        table(["", ""], rows)
        + "<h3>Phases</h3>"
        + table(["phase", "status", "wall s", "started", "finished", "config", "result"], phases)
        + f"<p>Total wall time of the phases: {total:,.1f} s.</p>"
        + "<h3>Preset</h3><pre>"
        + esc(json.dumps(manifest.get("config", {}), indent=1))
        + "</pre>"
    )


def _time(stamp: float | None) -> str:
    import time

    return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(stamp)) if stamp else ""


EXTRA_METRICS = {"racing": ("crash_rate",), "harvest": ("conflict", "equality")}  # shown beside the reward


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


def generator_section(run_dir: Path, results: dict) -> str:
    def render(env: str, res: dict) -> str:
        quality = res["quality"]
        recon = quality["reconstruction"]
        rows = [
            ["reconstruction: cell accuracy (VAE / mean image)", f"{fmt(recon['vae']['accuracy'])} / {fmt(recon['mean_image']['accuracy'])}"],
            ["reconstruction: on-cell IoU (VAE / mean image)", f"{fmt(recon['vae']['iou'])} / {fmt(recon['mean_image']['iou'])}"],
            ["held-out worlds", fmt(recon["worlds"])],
            ["training epochs", fmt(quality["training"]["epochs"])],
            ["final held-out loss", fmt(quality["training"]["final"]["holdout_loss"])],
        ]
        rows += [[name.replace("_", " "), fmt(value)] for name, value in quality.get(env, {}).items()]
        return table(["measure", "value"], rows) + image(
            run_dir / env / "figures" / "generator_traversals.png", f"{env}: latent traversals of G(z) (one row per latent dimension)"
        )

    return per_env(results, "generator", render, "quality", "no quality.json")


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
        rows += [[f"<td>mean {name.replace('_', ' ')}</td>" + number(f"{env}.random.{name}", random[name])] for name in EXTRA_METRICS[env]]
        figure = distribution_figure(
            {"random worlds": random["normalised"]},
            f"{res['metric']} (normalised)",
            run_dir / env / "figures" / "random.png",
            f"{env}: reward over {random['worlds']} random worlds",
        )
        return table(["", "value"], rows, raw_cells=True) + image(
            figure, f"{env}: distribution of the normalised reward over random worlds (cf. Figure 6a)"
        )

    return per_env(results, "random", render, "random", "no random campaign in the store")


def strategic_section(run_dir: Path, results: dict) -> str:
    def render(env: str, res: dict) -> str:
        extra = EXTRA_METRICS[env]
        rows = []
        for label in ("min", "max"):
            found = res[label]
            rows.append(
                [
                    f"<td>{label}imising world ({esc(found['campaign'])}, generation {found['generation']}, slot {found['slot']}; "
                    f"{found['evaluated']} worlds searched)</td>",
                    number(f"{env}.{label}.raw", found["raw"]),
                    number(f"{env}.{label}.normalised", found["normalised"]),
                    *[number(f"{env}.{label}.{name}", found[name]) for name in extra],
                ]
            )
        return table(["world", "reward (raw)", "reward (normalised)", *[n.replace("_", " ") for n in extra]], rows, raw_cells=True) + image(
            run_dir / env / "figures" / "strategic.png",
            f"{env}: the worlds CMA-ES found minimising and maximising reward, against random worlds (cf. Figures 1, 6b)",
        )

    return per_env(results, "strategic", render, "min", "no strategic campaigns in the store")


def comparison_section(run_dir: Path, results: dict) -> str:
    from worldagent.reports.comparison import comparison_figure, sample_efficiency

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
        figure = comparison_figure(runs, random, res["metric"], run_dir / env / "figures" / "comparison.png", maximize=False)
        return (
            table(head, body, raw_cells=True)
            + "<p>Worlds each optimiser evaluated (median over seeds) before its first world scoring at or below the random "
            "distribution's q-quantile; random sampling needs 1/q on average.</p>"
            + image(figure, f"{env}: rewards of the worlds each optimiser sampled while minimising reward, against random worlds (cf. Figure 7)")
        )

    return per_env(results, "compare", render)


def influence_section(run_dir: Path, results: dict) -> str:
    def render(env: str, res: dict) -> str:
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
        return (
            f"<p>Selection <code>{esc(result['selection']['describe'])}</code>: {worlds['selected']} of {worlds['tried']} candidate worlds "
            f"became the influenced training distribution; agents trained with seeds {esc(result['config']['seeds'])}, "
            f"evaluated on {result['config']['eval_worlds']} random worlds x {result['config']['repeats']} episodes.</p>"
            + table(["metric", "default training (mean over seeds)", "95% CI ±", "influenced training", "95% CI ±"], rows, raw_cells=True)
            + image(
                run_dir / env / "figures" / "influence.png",
                f"{env}: default against influenced training, with worlds of the influenced distribution (cf. Figure 8)",
            )
        )

    return per_env(results, "influence", render, "influence", "no influence.json")


def headline_section(rows: list[Headline]) -> str:
    body = [
        [
            f"<td>{esc(row.label)}</td>",
            number(row.key, row.ours),
            f"<td class='num'>{'–' if row.paper is None else fmt(row.paper)}</td>",
            f"<td>{esc(row.note)}</td>",
        ]
        for row in rows
    ]
    return (
        table(["quantity", "ours", "paper", "note"], body, raw_cells=True)
        + "<p>Ours are recomputed from the run stores when the report is built (n/a: the phase has not run; –: the paper gives no number). "
        "Normalised: racing by the return's rule-given range, harvest by the run's best single-episode group reward "
        "(see the module docstring of <code>worldagent.reports.html</code>).</p>"
    )


# -- the report -------------------------------------------------------------------------------


def build_report(run_dir: Path | str) -> Path:
    """Write ``run_dir/report.html`` from the manifest, the stores and the phases' outputs.

    Args:
        run_dir: a ``worldagent reproduce`` run directory.

    Returns:
        The report's path.
    """
    from worldagent.reproduce.manifest import Manifest

    run_dir = Path(run_dir)
    manifest = Manifest.read(run_dir).data
    envs = [env for env in ENVS if env in manifest.get("envs", [])]
    if not envs:
        raise WorldagentError(f"{run_dir}/manifest.json names no environment; run `worldagent reproduce --out {run_dir}` first.")
    results = {env: env_results(run_dir, env, manifest) for env in envs}
    bodies = {
        "overview": overview(manifest, run_dir),
        "generator": generator_section(run_dir, results),
        "training": training_section(run_dir, results),
        "random": random_section(run_dir, results),
        "strategic": strategic_section(run_dir, results),
        "comparison": comparison_section(run_dir, results),
        "influence": influence_section(run_dir, results),
        "headline": headline_section(headlines(results)),
    }
    nav = "<nav>" + "".join(f'<a href="#{anchor}">{esc(title)}</a>' for anchor, title in SECTIONS) + "</nav>"
    title = f"worldagent reproduce: {manifest.get('preset', '?')} ({', '.join(envs)})"
    page = (
        f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>{esc(title)}</title><style>{CSS}</style></head><body>"
        f"<h1>{esc(title)}</h1><p>Optimising Worlds to Evaluate and Influence Reinforcement Learning Agents, reproduced end to end.</p>"
        + nav
        + "".join(section(anchor, heading, bodies[anchor]) for anchor, heading in SECTIONS)
        + "</body></html>\n"
    )
    return write_text(run_dir / REPORT_FILE, page)
