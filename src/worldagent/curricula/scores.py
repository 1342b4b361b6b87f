"""What a curriculum ranks worlds by: learning potential, or how close an episode came to a user's target.

- Learning potential (PLR's default, Jiang et al. 2021): the positive value loss, the mean over
  an episode's steps of max(target - V, 0) for actor-critics (their GAE or n-step targets), and
  the mean |TD error| of its transitions for DQN. The trainer supplies the per-step values.
- A target (``--target``): an event in the language of ``worldagent.events`` ("crash_rate > 0.5",
  "lap_rate < 0.5 and return < 0"), scored per episode by its *margin*, how far the episode's
  metrics are inside the event (the smallest over its clauses, so that every clause counts);
  or one metric to maximise or minimise ("conflict", ``maximize=False``). Averaged over a
  world's episodes, the margin of ``crashed > 0.5`` is the world's crash rate less 0.5: the
  buffer ranks worlds by the very property the paper's offline influence selects them for.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp

from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.events import parse_selection

_MARGIN = {
    ">": lambda value, number: value - number,
    ">=": lambda value, number: value - number,
    "<": lambda value, number: number - value,
    "<=": lambda value, number: number - value,
    "==": lambda value, number: -jnp.abs(value - number),
    "!=": lambda value, number: jnp.abs(value - number),
}


@dataclass(frozen=True)
class TargetScore:
    """Scores an episode's metrics by a target: higher is more what the user asked for (hashable, jittable).

    Attributes:
        text: the target as written.
        clauses: ``(metric, op, number)`` of an event; or ``((metric, ">", 0.0),)`` / ``"<"`` for
            a metric to maximise / minimise (the margin is then the metric itself, signed).
    """

    text: str
    clauses: tuple[tuple[str, str, float], ...]

    @property
    def metrics(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(metric for metric, _, _ in self.clauses))

    def __call__(self, metrics: dict) -> jnp.ndarray:
        """f32[...]: the margin of episodes whose metrics ``{name: f32[...]}`` are given."""
        margins = [_MARGIN[op](jnp.asarray(metrics[metric], jnp.float32), number) for metric, op, number in self.clauses]
        return jnp.min(jnp.stack(margins), axis=0)


def target_score(env, text: str, maximize: bool | None = None) -> TargetScore:
    """The ``TargetScore`` of ``text`` for ``env`` (a name or spec): an event, or with ``maximize`` set, one metric.

    Online scoring reads each episode's own metrics (``env.metrics``), so derived metrics (e.g.
    racing's normalised return) are refused with the raw metric to use instead.
    """
    spec = registry.get(env)
    raw = _episode_metric_names(spec)
    if maximize is not None:
        metric = spec.metrics.resolve(text.strip())
        clauses = ((metric, ">" if maximize else "<", 0.0),)
    else:
        if not any(op in text for op in ("<", ">", "=")):
            raise WorldagentError(
                f"target {text!r} is a metric, not an event: add --maximize or --minimize, or write an event such as 'crash_rate > 0.5'."
            )
        selection = parse_selection(text, spec.name)
        clauses = tuple((clause.metric, clause.op, float(clause.number)) for clause in selection.clauses)
    for metric, _, _ in clauses:
        if metric not in raw:
            raise WorldagentError(f"target metric {metric!r} is computed after episodes, not during training; target one of {', '.join(raw)}.")
    shown = text.strip() if maximize is None else f"{text.strip()} ({'maximize' if maximize else 'minimize'})"
    return TargetScore(shown, clauses)


def requested_target(env, text: str | None, maximize: bool | None) -> TargetScore | None:
    """The target of ``--target`` / ``--maximize`` / ``--minimize`` (None when no ``--target``); a direction without a target is refused."""
    if text is None:
        if maximize is not None:
            raise WorldagentError("--maximize/--minimize direct a --target metric; add --target METRIC (e.g. --target conflict --minimize).")
        return None
    return target_score(env, text, maximize)


def _episode_metric_names(spec) -> tuple[str, ...]:
    """The metrics the env itself reports per episode (``env.metrics``), read off shapes only."""
    import jax
    import numpy as np

    env, params = spec.make_env()
    world = jax.tree_util.tree_map(lambda leaf: leaf[0], spec.generate(np.zeros(1, np.int64)))
    _, state = jax.eval_shape(env.reset, jax.random.key(0), world, params)
    return tuple(jax.eval_shape(env.metrics, state))


def positive_value_loss(targets: jnp.ndarray, values: jnp.ndarray) -> jnp.ndarray:
    """f32[...]: max(target - V, 0) per step, the robust-PLR score's summand."""
    return jnp.maximum(targets - values, 0.0)
