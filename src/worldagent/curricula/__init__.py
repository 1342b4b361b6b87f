"""Curricula: where each training episode's world comes from, adapting while the agent learns (issue 25).

A curriculum wraps a world distribution (``agents/distributions.py``) and is passed to a trainer
in its place. It is a pytree with a small interface, all pure and jitted inside the training
program (no host round trip per episode)::

    state = curriculum.init(key)                             # part of the trainer state
    draw = curriculum.sample(state, key, n)                  # next worlds of n envs: z, slot, worlds
    state = curriculum.update(state, z, slot, score, valid)  # after episodes end, with their scores
    slot = curriculum.slot_of(state, z, slot)                # where the worlds in play now sit in it
    score = curriculum.episode_score(potential, metrics)     # what the trainer measured -> score

Every module in this package with a ``build(worlds, settings, target)`` is a curriculum, found
by its module name (``dr``, ``plr``, ``accel``, ``target``): a new curriculum is one new file.
"""

from __future__ import annotations

import dataclasses
import importlib
import pkgutil
import typing
from functools import cache
from typing import Any

import numpy as np

from worldagent.configs import describe_field, parse_field
from worldagent.errors import WorldagentError

DEFAULT = "dr"


@cache
def curricula() -> dict[str, Any]:
    """{name: module} of every curriculum (modules of this package that define ``build``)."""
    modules = (importlib.import_module(f"{__name__}.{info.name}") for info in pkgutil.iter_modules(__path__))
    return {module.__name__.rsplit(".", 1)[-1]: module for module in modules if hasattr(module, "build")}


def describe() -> str:
    """One line per curriculum, for ``--help``."""
    return "; ".join(f"{name}: {module.HELP}" for name, module in curricula().items())


def make_curriculum(name: str, worlds: Any, settings: dict | None = None, target=None) -> Any:
    """The curriculum ``name`` over the distribution ``worlds``.

    Args:
        name: a curriculum's name (``curricula()``).
        worlds: the distribution it draws from (``LatentWorlds`` for all but ``dr``).
        settings: {setting: value} over the curriculum's defaults (``replay.Settings``).
        target: a ``scores.TargetScore`` to score episodes by (``scores.target_score``), or None.
    """
    table = curricula()
    if name not in table:
        raise WorldagentError(f"unknown curriculum {name!r}; use one of {', '.join(table)}.")
    return table[name].build(worlds, dict(settings or {}), target)


def check_request(name: str, settings: dict, worlds_have_latents: bool) -> None:
    """Refuse a curriculum request before any world is built: an unknown name, bad settings, or latents missing."""
    table = curricula()
    if name not in table:
        raise WorldagentError(f"unknown curriculum {name!r}; use one of {', '.join(table)}.")
    if getattr(table[name], "LATENTS", False) and not worlds_have_latents:
        raise WorldagentError(f"curriculum {name!r} draws latents of a generator; train on --worlds vae --generator DIR (or use --curriculum dr).")
    if settings and getattr(table[name], "LATENTS", False):
        from worldagent.curricula.replay import Settings

        Settings(**settings)  # range checks, one line each


def label(curriculum: Any) -> str:
    """How a run's curriculum is written in ``run.json`` (so a resumed run must use the same one)."""
    if not getattr(curriculum, "adaptive", False):
        return "dr"
    from worldagent.curricula.replay import Settings

    changed = {f.name: getattr(curriculum.settings, f.name) for f in dataclasses.fields(Settings)}
    target = f" target={curriculum.target.text!r}" if curriculum.target is not None else ""
    return f"{curriculum.name} " + " ".join(f"{k}={v}" for k, v in changed.items()) + target


LATE_REPLAY = 0.25  # share of a run's episodes after which a buffer still filling is worth a warning


def late_replay_warning(curriculum: Any, episodes: int) -> str | None:
    """One line when a replay curriculum cannot start replaying in the first quarter of ``episodes``.

    Replay waits until ``min_fill`` of the buffer holds distinct worlds, about one per episode:
    the papers' 4,000 latents suit their budgets, not a run of a few thousand episodes, where
    the curriculum would stay ``dr`` for most or all of training. Suggests a buffer that starts
    replay a tenth of the way in.
    """
    settings = getattr(curriculum, "settings", None)
    if not getattr(curriculum, "adaptive", False) or settings is None or settings.replay_prob == 0:
        return None
    needed = int(np.ceil(settings.min_fill * settings.buffer_size))
    if needed <= LATE_REPLAY * episodes:
        return None
    suggested = max(1, int(0.1 * episodes / max(settings.min_fill, 1e-9)))
    when = "never replays" if needed >= episodes else f"replays only after ~{needed:,} of its {episodes:,} episodes"
    return (
        f"curriculum {curriculum.name}: a buffer of {settings.buffer_size:,} with min_fill {settings.min_fill} {when}; "
        f"for this budget pass --curriculum-set buffer_size={suggested}."
    )


def is_robust(distribution: Any) -> bool:
    """Whether a trainer's distribution lets the learner use only some steps (robust PLR): known when tracing."""
    return bool(getattr(getattr(distribution, "settings", None), "robust", False))


def as_curriculum(distribution: Any) -> Any:
    """A trainer's ``distribution`` argument as a curriculum: a fixed distribution becomes ``dr``."""
    if hasattr(distribution, "adaptive"):
        return distribution
    from worldagent.curricula.dr import DomainRandomisation

    return DomainRandomisation(distribution)


def parse_curriculum_settings(texts: list[str] | tuple[str, ...]) -> dict[str, Any]:
    """``["buffer_size=1000", "replay_prob=0.8"]`` -> {field: typed value} of ``replay.Settings``; bad ones refused in one line."""
    from worldagent.curricula.replay import Settings

    hints = typing.get_type_hints(Settings)
    parsed: dict[str, Any] = {}
    for text in texts:
        name, sep, value = text.partition("=")
        name = name.strip()
        if not sep or name not in hints:
            raise WorldagentError(f"--curriculum-set {text!r}: write NAME=VALUE with NAME one of {', '.join(hints)}.")
        try:
            parsed[name] = parse_field(value.strip(), hints[name])
        except ValueError:
            raise WorldagentError(f"--curriculum-set {text!r}: {name} takes {describe_field(hints[name])}.") from None
    return parsed
