"""The curriculum figure: what a curriculum steered training toward, from its buffer snapshots.

Left: the buffer's scores over training (median, 90th percentile and maximum of the latents it
held at each checkpoint) and how full it was. Middle: the last buffer's latents on a 2-D
projection (the two principal axes of the latents), coloured by score. Right: the worlds it
favoured most at the end (highest score), decoded by the generator and drawn as the environment
draws worlds.

``curriculum_section`` is the report's "Curriculum" section: per environment, what the agent
phase's curriculum was (``runs.Run.curriculum``), this figure redrawn from the agent's
snapshots, and the latents it favoured most: found (the buffer's score, the figure the curriculum
selected them on) beside confirmed (the final agent on fresh episodes, ``analysis.favoured``, read
back from the store by ``runs``: nothing here plays an episode); for ``dr`` one line on how to ask
for one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from worldagent.curricula.snapshots import FAVOURITES, favourite_order
from worldagent.files import write_atomically


def score_trace(snapshots: list[dict]) -> dict[str, np.ndarray]:
    """{update, filled, median, p90, max}: f64[S] per snapshot (NaN scores where the buffer was empty)."""
    quantile = lambda s, q: float(np.quantile(s["score"], q)) if len(s["score"]) else np.nan  # noqa: E731
    return {
        "update": np.array([int(s["update"]) for s in snapshots], np.float64),
        "filled": np.array([len(s["score"]) for s in snapshots], np.float64),
        "median": np.array([quantile(s, 0.5) for s in snapshots]),
        "p90": np.array([quantile(s, 0.9) for s in snapshots]),
        "max": np.array([quantile(s, 1.0) for s in snapshots]),
    }


def principal_plane(z: np.ndarray) -> np.ndarray:
    """f64[M, 2]: latents ``z`` f[M, D] on their two principal axes (centred; fewer axes are zero-padded)."""
    z = np.asarray(z, np.float64)
    centred = z - z.mean(axis=0)
    if len(z) < 2:
        return np.zeros((len(z), 2))
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    plane = centred @ axes[:2].T
    return np.pad(plane, ((0, 0), (0, 2 - plane.shape[1])))


def favourite_latents(snapshot: dict, count: int) -> np.ndarray:
    """f32[k, D]: the ``count`` latents of highest score in a snapshot (best first)."""
    return np.asarray(snapshot["z"], np.float32)[favourite_order(snapshot, count)]


def curriculum_figure(snapshots: list[dict], spec: Any, generator: Any, out: Path | str, count: int = 4, title: str = "") -> Path:
    """Draw the curriculum figure (see module docstring) of a run's ``snapshots`` to ``out`` (PNG).

    Args:
        snapshots: ``curricula.snapshots.load_snapshots(run_dir)`` (at least one).
        spec: the env spec (its pictures draw the favoured worlds).
        generator: the ``Generator`` the latents decode with (None: no pictures).
        count: favoured worlds drawn.
    """
    import jax
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    trace, last = score_trace(snapshots), snapshots[-1]
    favourites = favourite_latents(last, count) if generator is not None else np.zeros((0, 0))
    columns = 2 + len(favourites)
    figure = plt.figure(figsize=(4.0 * 2 + 2.2 * len(favourites), 3.6))
    grid = figure.add_gridspec(1, columns, width_ratios=[4, 4] + [2.2] * len(favourites))

    ax = figure.add_subplot(grid[0, 0])
    for name, style in (("median", "-"), ("p90", "--"), ("max", ":")):
        ax.plot(trace["update"], trace[name], style, marker=".", label=name)  # a marker: a run of one snapshot shows too
    ax.set_xlabel("update")
    ax.set_ylabel("buffer score")
    ax.legend(fontsize=7, loc="best")
    filled = ax.twinx()
    filled.plot(trace["update"], trace["filled"], color="0.7", lw=1)
    filled.set_ylabel("latents held", color="0.5")

    ax = figure.add_subplot(grid[0, 1])
    plane = principal_plane(last["z"])
    points = ax.scatter(plane[:, 0], plane[:, 1], c=last["score"], s=8, cmap="viridis")
    figure.colorbar(points, ax=ax, label="score")
    ax.set_title(f"buffer at update {int(last['update'])}", fontsize=9)
    ax.set_xlabel("latent PC 1")
    ax.set_ylabel("latent PC 2")

    if len(favourites):
        worlds = generator(jax.numpy.asarray(favourites))
        scores = np.sort(np.asarray(last["score"]))[::-1]
        for i in range(len(favourites)):
            ax = figure.add_subplot(grid[0, 2 + i])
            ax.imshow(spec.pictures.world(jax.tree_util.tree_map(lambda leaf, i=i: leaf[i], worlds), 128))
            ax.set_title(f"favoured #{i + 1}\nscore {scores[i]:.3g}", fontsize=8)
            ax.axis("off")
    if title:
        figure.suptitle(title, fontsize=10)
    figure.tight_layout()

    def save(tmp: Path) -> None:
        figure.savefig(tmp, format="png", dpi=110)

    try:
        return write_atomically(out, save)
    finally:
        plt.close(figure)


# -- the report's section -----------------------------------------------------------------------

SHOWN_DIMENSIONS = 8  # latent coordinates written out per favoured latent


def curriculum_section(run: Any, results: dict) -> str:
    """The report's "Curriculum" section: one block per environment (see the module docstring)."""
    from worldagent.reports.page import missing, phase_state

    parts = []
    for env, res in results.items():
        state = phase_state(res["phases"]["agent"])
        found = res.get("curriculum")
        parts.append(f"<h3>{env}</h3>" + (state or (missing("no agent run") if found is None else _curriculum_block(run, env, res, found))))
    return "".join(parts) or missing("not run")


def _curriculum_block(run: Any, env: str, res: dict, found: dict) -> str:
    from worldagent.agents.algorithms import get_algorithm
    from worldagent.envs import registry
    from worldagent.reports.page import esc, image, missing

    request = found["request"]
    if request is None:
        worlds = res["phases"]["dataset"].get("config", {}).get("worlds")
        return (
            f"<p data-curriculum='dr'>No curriculum: the agent trained with <code>dr</code> (domain randomisation), every episode's world drawn "
            f"afresh from the dataset's {'' if worlds is None else f'{worlds:,} '}procedural worlds. To let a curriculum choose them from the run's "
            "G(z) as the agent learns, run reproduce with <code>--curriculum plr</code> (or accel, target; docs/curriculum.md).</p>"
        )
    target, algo = request.get("target"), res["phases"]["agent"].get("config", {}).get("algo")
    potential = get_algorithm(algo).learning_potential
    direction = {True: " (maximize)", False: " (minimize)"}.get(request.get("maximize"), "")
    scored = f"learning potential ({potential})" if target is None else f"the margin of the target <code>{esc(target)}</code>{direction}"
    text = (
        f"<p data-curriculum='{esc(request['name'])}'>The agent trained with the curriculum <code>{esc(request['name'])}</code> over latents z of "
        f"the run's G(z), each world scored by {scored}. As the agent's run.json records it: <code>{esc(found['label'])}</code>.</p>"
    )
    snapshots = found["snapshots"]
    if not snapshots:
        return text + missing("no buffer snapshot in the agent's run directory")
    spec = registry.get(env)
    generator = run.generator(env) if run.has_generator(env) else None
    figure = curriculum_figure(snapshots, spec, generator, res["layout"].figure("curriculum"), count=FAVOURITES, title=f"{env}: {request['name']}")
    caption = (
        f"{env}: the buffer's scores over training ({len(snapshots)} snapshot{'s' if len(snapshots) != 1 else ''}), its latents at the end on their two principal axes, "
        "and the worlds G(z) of the latents it favoured most"
    )
    return text + image(figure, caption) + favourites_table(env, snapshots[-1], found.get("favoured"))


def favourites_table(env: str, snapshot: dict, favoured: dict | None = None) -> str:
    """The last snapshot's highest-scoring latents: found (the buffer's score, episodes, age) beside confirmed (the
    main metric and the failure rate on fresh episodes, 95% intervals; ``runs.Run.curriculum``'s ``favoured``), the
    coordinates (rounded), and how many are confirmed harder than average."""
    from worldagent.reports.page import fmt, missing, number, table

    held = len(snapshot["score"])
    if not held:
        return missing(f"the buffer held no latent at update {int(snapshot['update']):,} (no episode had ended)")
    order = favourite_order(snapshot, FAVOURITES)
    worlds = (favoured or {}).get("worlds") or [None] * len(order)
    metric, failure = (favoured or {}).get("metric", "main metric"), (favoured or {}).get("failure")
    rows = []
    for rank, (slot, world) in enumerate(zip(order, worlds), start=1):
        z = np.asarray(snapshot["z"][slot], np.float64)
        shown = " ".join(f"{v:.2f}" for v in z[:SHOWN_DIMENSIONS]) + (" …" if len(z) > SHOWN_DIMENSIONS else "")
        key = f"{env}.curriculum.favoured{rank}"
        rows.append(
            [
                f"<td>#{rank}</td>",
                number(f"{key}.score", float(snapshot["score"][slot])),
                f"<td class='num'>{fmt(int(snapshot['count'][slot]))}</td>",
                f"<td class='num'>{fmt(int(snapshot['age'][slot]))}</td>",
                interval_cell(f"{key}.confirmed", None if world is None else world.confirmed(metric)),
                interval_cell(f"{key}.failure_rate", None if world is None or failure is None else world.failure_rate(failure), 3),
                f"<td class='num'>{fmt(float(np.linalg.norm(z)), 3)}</td>",
                f"<td><code>{shown}</code></td>",
            ]
        )
    repeats = next((w.repeats for w in worlds if w is not None), None)
    fresh = "not confirmed" if repeats is None else f"{repeats} fresh episodes"
    head = [
        "favoured",
        f"found: the buffer's score ({(favoured or {}).get('scored_by') or 'the selection'})",
        "episodes scored",
        "episodes since last scored",
        f"confirmed {metric} [95%] ({fresh})",
        f"confirmed failure rate [95%]{'' if failure is None else f' ({failure.describe()})'}",
        "|z|",
        f"z (first {min(len(snapshot['z'][0]), SHOWN_DIMENSIONS)} dimensions)",
    ]
    title = (
        f"<h4>The latents it favoured most, of {held:,} held at update {int(snapshot['update']):,}: found (the buffer's score) beside confirmed</h4>"
    )
    return title + table(head, rows, raw_cells=True) + favoured_verdict(env, favoured)


def interval_cell(key: str, interval: Any, digits: int = 4) -> str:
    """A confirmed figure's cell: its mean (machine-readable) and 95% interval; "n/a" when not confirmed."""
    from worldagent.reports.page import fmt, number

    if interval is None:
        return number(key, None)
    return number(key, interval.mean, digits, f" [{fmt(interval.low, 3)}, {fmt(interval.high, 3)}]")


def favoured_verdict(env: str, favoured: dict | None) -> str:
    """The paragraph under the favourites table: "k of N favoured worlds confirmed harder than average", the
    baseline it compares with, or why there is no verdict."""
    from worldagent.analysis.favoured import favoured_line, harder_count
    from worldagent.reports.page import esc, missing

    if not favoured or not any(w is not None for w in favoured["worlds"]):
        return missing(
            "The favoured worlds were not confirmed on fresh episodes (a run from before confirmation): their scores above are the "
            "buffer's selection, partly luck (docs/noise.md)."
        )
    failure, baseline = favoured["failure"], favoured["baseline"]
    line = favoured_line(favoured["worlds"], favoured["metric"], failure, baseline)
    attributes = ""
    if failure is not None and baseline is not None:
        k, n = harder_count(favoured["worlds"], failure, baseline)
        attributes = f" data-key='{esc(env)}.curriculum.harder' data-value='{k}' data-of='{n}'"
    return (
        f"<p class='favoured-verdict'{attributes}>{esc(line[0].upper() + line[1:])}. Found is the buffer's own score, the figure the "
        "curriculum selected them on (partly luck, docs/noise.md); confirmed is the final agent on the same world G(z) on fresh episodes "
        "no search or training drew.</p>"
    )
