"""Played episodes as the page animates them: paths in picture pixels, who is on the map, metrics,
and the env's marks at each step.

Where an agent is on a world's picture is the environment's to say (``Pictures.locate``); an
environment without it gets its own still picture of the episodes (``Pictures.episodes``).
What else changes during an episode (harvest's apples and beams) is the environment's too
(``Pictures.marks``): ``replay_marked`` records it at every step of the replay, and the payload
carries each kind of mark as the steps where some appear or vanish.
"""

from __future__ import annotations

import dataclasses
import functools
import io
from typing import Any

import numpy as np


def replay_marked(spec, env, policy, world: Any, keys, params: Any):
    """``trajectories.replay``, recording ``spec.pictures.marks`` at every step as well.

    The marks ride in the replay's trace: ``marked_trace`` appends their positions and shown
    flags to the agents' as extra rows, and they are split off again here, so the episodes are
    played exactly as ``replay`` plays them (jitted or by the host evaluator). An env without
    marks is replayed with its own trace (the same compiled program as everywhere else).

    Returns:
        ``(Episodes, {kind: (positions [E, T+1, K, P], shown bool[E, T+1, K])})``.
    """
    from worldagent.evaluation.trajectories import Episodes, replay

    if spec.pictures.marks is None:
        return replay(spec, env, policy, world, keys, params), {}
    trace = marked_trace(spec.trace, spec.pictures.marks, env)
    (agent_shape, agent_dtype, present_shape), kinds = mark_layout(spec.trace, spec.pictures.marks, env, world, params)
    played = replay(dataclasses.replace(spec, trace=trace), env, policy, world, keys, params)
    count = int(np.prod(present_shape, dtype=int))
    lead = played.present.shape[:2]
    agents = Episodes(
        played.positions[:, :, :count].reshape(*lead, *agent_shape).astype(agent_dtype, copy=False),  # as ``trace`` gives them
        played.present[:, :, :count].reshape(*lead, *present_shape),
        played.steps,
        played.metrics,
    )
    marks, start = {}, count
    for kind, rows in kinds:
        marks[kind] = (played.positions[:, :, start : start + rows], played.present[:, :, start : start + rows])
        start += rows
    return agents, marks


def traced_parts(trace, marks, env, state):
    """``((positions, present), {kind: (positions [K, P], shown [K])})`` of one state, kinds in name order."""
    return trace(state), dict(sorted(marks(env, state).items()))


@functools.lru_cache(maxsize=16)
def marked_trace(trace, marks, env):
    """``state -> (rows [A + ΣK, P], shown bool[A + ΣK])``: ``trace``'s A agents, then each kind's K
    marks (``mark_layout`` says how many of which). One function per (trace, marks, env), so the
    replay compiles once."""
    import jax.numpy as jnp

    def packed(state):
        (positions, present), found = traced_parts(trace, marks, env, state)
        width = positions.shape[-1]
        rows = [jnp.reshape(positions, (-1, width))] + [jnp.reshape(where, (-1, width)) for where, _ in found.values()]
        shown = [jnp.reshape(present, (-1,))] + [jnp.reshape(there, (-1,)) for _, there in found.values()]
        return jnp.concatenate(rows), jnp.concatenate(shown).astype(bool)

    return packed


_LAYOUTS: dict = {}
LAYOUTS_KEPT = 16


def mark_layout(trace, marks, env, world: Any, params: Any) -> tuple:
    """``((agent positions' shape and dtype, present's shape), ((kind, K), ...))`` of ``marked_trace``'s rows
    (from the shapes alone: nothing runs), kept per (trace, marks, env, world shapes)."""
    import jax

    key = (trace, marks, env, tuple((np.shape(leaf), np.asarray(leaf).dtype.str) for leaf in jax.tree_util.tree_leaves(world)))
    if key not in _LAYOUTS:
        if len(_LAYOUTS) >= LAYOUTS_KEPT:  # a long-lived server sees many worlds' shapes: keep the last few
            _LAYOUTS.clear()

        def shapes(world, params):
            _, state = env.reset(jax.random.key(0), world, params)
            return traced_parts(trace, marks, env, state)

        (positions, present), found = jax.eval_shape(shapes, world, params)
        kinds = tuple((kind, int(np.prod(there.shape, dtype=int))) for kind, (_, there) in found.items())
        _LAYOUTS[key] = ((tuple(positions.shape), np.dtype(positions.dtype), tuple(present.shape)), kinds)
    return _LAYOUTS[key]


def episodes_payload(spec, world: Any, played, params: Any, size: int, marks: dict | None = None) -> dict:
    """JSON of replayed episodes: per episode its path in picture pixels [steps + 1][agents][2], who
    is on the map, its metrics, and its ``marks`` (``replay_marked``) as ``mark_changes`` says."""
    positions, present = played.positions, played.present
    if positions.ndim == 3:  # one agent: [E, T+1, 2] -> [E, T+1, 1, 2]
        positions, present = positions[:, :, None], present[:, :, None]
    locate = spec.pictures.locate
    pixels = np.asarray(locate(positions, world, size)) if locate else None
    marked = (
        {kind: mark_changes(where, shown, played.steps, lambda p: locate(p, world, size)) for kind, (where, shown) in (marks or {}).items()}
        if locate
        else {}
    )
    metrics = spec.metrics.with_derived({k: np.asarray(v) for k, v in played.metrics.items()}, params)
    runs = []
    for e in range(len(played)):
        end = int(played.steps[e]) + 1
        run = {
            "steps": int(played.steps[e]),
            "path": None if pixels is None else np.round(pixels[e, :end], 1).tolist(),
            "present": np.asarray(present[e, :end]).astype(int).tolist(),
            "metrics": {name: np.round(np.asarray(v[e], np.float64), 4).tolist() for name, v in metrics.items()},
        }
        if marked:
            run["marks"] = {kind: changes[e] for kind, changes in marked.items()}
        runs.append(run)
    means = {name: float(np.mean(np.asarray(v, np.float64))) for name, v in metrics.items()}
    still = still_picture(spec, world, played, size) if pixels is None else None
    styles = {kind: mark_style(spec.pictures.mark_styles.get(kind, {}), size, kind) for kind in marked} or None
    outcomes = {name: mark_style(style, size, name) for name, style in spec.pictures.outcomes.items() if name in metrics} if locate else {}
    return {"size": size, "episodes": runs, "means": means, "still": still, "marks": styles, "outcomes": outcomes or None}


def mark_changes(positions, shown, steps, locate) -> list[list]:
    """Per episode, the steps where marks of one kind appear or vanish: ``[[step, appeared [[x, y], ...],
    vanished [[x, y], ...]], ...]`` in picture pixels (step 0: every mark there at the start).

    ``positions`` [E, T+1, K, P] and ``shown`` bool[E, T+1, K] as ``replay_marked`` records them; a
    mark that moves while shown vanishes from its old place and appears at its new one. Only
    the changes are sent (apples come and go a few at a time), and only they are located.
    """
    positions, shown = np.asarray(positions), np.asarray(shown, bool)
    within = np.arange(shown.shape[1])[None, :, None] <= np.asarray(steps)[:, None, None]  # frozen after the end
    shown = shown & within
    before = np.zeros_like(shown)
    before[:, 1:] = shown[:, :-1]
    moved = np.zeros_like(shown)
    moved[:, 1:] = moved_marks(positions) & shown[:, 1:] & shown[:, :-1]
    e, t, k = np.nonzero((shown != before) | moved)
    appear, vanish = shown[e, t, k], before[e, t, k]  # a moved mark does both
    changes: list[dict] = [{} for _ in range(len(shown))]
    for flags, offset, slot in ((vanish, 1, 2), (appear, 0, 1)):
        if not flags.any():
            continue
        where = positions[e[flags], t[flags] - offset, k[flags]]
        pixels = np.round(np.asarray(locate(where), np.float64), 1).tolist()
        for episode, step, xy in zip(e[flags].tolist(), t[flags].tolist(), pixels):
            changes[episode].setdefault(step, [step, [], []])[slot].append(xy)
    return [[found[step] for step in sorted(found)] for found in changes]


def moved_marks(positions: np.ndarray) -> np.ndarray:
    """bool[E, T, K]: mark k's position at step t + 1 differs from step t (positions [E, T+1, K, P])."""
    width = positions.shape[-1] * positions.dtype.itemsize
    if width in (4, 8) and positions.dtype.kind in "iu":  # (row, col) cells: one integer compare a mark
        packed = np.ascontiguousarray(positions).view(np.int32 if width == 4 else np.int64)[..., 0]
        return packed[:, 1:] != packed[:, :-1]
    return (positions[:, 1:] != positions[:, :-1]).any(-1)


def mark_style(style, size: int, kind: str = "") -> dict:
    """A kind's ``Pictures.mark_styles`` (or ``outcomes``) entry for the page: its radius in picture
    pixels (at least one) and its legend label (default: the kind's name)."""
    return {
        "shape": str(style.get("shape", "dot")),
        "colour": str(style.get("colour", "#ffffff")),
        "radius": round(max(1.0, float(style.get("radius", 0.01)) * size), 2),
        "label": str(style.get("label", kind)),
    }


def picture_key(pictures, size: int = 384) -> dict:
    """What the World view's legend names: the picture's colours, each kind of mark, the agents and the
    outcome marks (``Pictures.legend``, ``mark_styles``, ``agents``, ``outcomes``)."""
    return {
        "colours": dict(pictures.legend),
        "marks": {kind: mark_style(style, size, kind) for kind, style in pictures.mark_styles.items()},
        "agents": list(pictures.agents),
        "outcomes": {name: mark_style(style, size, name) for name, style in pictures.outcomes.items()},
        "agent_colours": agent_colours(pictures),
    }


# For an env whose pictures name no agent colours: colours that no floor, wall or road has.
AGENT_COLOURS = ("#f24040", "#408cff", "#ffa61a", "#d959f2", "#00d8ff", "#ffd400", "#ffffff", "#8a2be2")


def agent_colours(pictures) -> list[str]:
    """The CSS colours the World view draws the agents of an env with several in: the env's own
    (``Pictures.agent_colours``, those its figures use), else ``AGENT_COLOURS``, one per agent ``Pictures.agents``
    names; empty for one agent, whose episodes each get their own colour instead."""
    if len(pictures.agents) < 2:
        return []
    return list(pictures.agent_colours or AGENT_COLOURS)[: len(pictures.agents)]


def still_picture(spec, world: Any, played, size: int) -> str | None:
    """The env's own picture of the episodes (``pictures.episodes``) as a data URL: what an env without ``locate`` shows instead of the animation."""
    if spec.pictures.episodes is None:
        return None
    import base64

    from worldagent.reports.figures import _pyplot

    plt = _pyplot()
    figure, axis = plt.subplots(figsize=(size / 100, size / 100), dpi=100)
    spec.pictures.episodes(axis, world, played)
    axis.set_xticks([])
    axis.set_yticks([])
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", bbox_inches="tight")
    plt.close(figure)
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode()
