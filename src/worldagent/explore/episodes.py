"""Played episodes as the page animates them: paths in picture pixels, who is on the map, metrics.

Where an agent is on a world's picture is the environment's to say (``Pictures.locate``); an
environment without it gets its own still picture of the episodes (``Pictures.episodes``).
"""

from __future__ import annotations

import io
from typing import Any

import numpy as np


def episodes_payload(spec, world: Any, played, params: Any, size: int) -> dict:
    """JSON of replayed episodes: per episode its path in picture pixels [steps + 1][agents][2], who is on the map, its metrics."""
    positions, present = played.positions, played.present
    if positions.ndim == 3:  # one agent: [E, T+1, 2] -> [E, T+1, 1, 2]
        positions, present = positions[:, :, None], present[:, :, None]
    pixels = np.asarray(spec.pictures.locate(positions, world, size)) if spec.pictures.locate else None
    metrics = spec.metrics.with_derived({k: np.asarray(v) for k, v in played.metrics.items()}, params)
    runs = []
    for e in range(len(played)):
        end = int(played.steps[e]) + 1
        runs.append(
            {
                "steps": int(played.steps[e]),
                "path": None if pixels is None else np.round(pixels[e, :end], 1).tolist(),
                "present": np.asarray(present[e, :end]).astype(int).tolist(),
                "metrics": {name: np.round(np.asarray(v[e], np.float64), 4).tolist() for name, v in metrics.items()},
            }
        )
    means = {name: float(np.mean(np.asarray(v, np.float64))) for name, v in metrics.items()}
    still = still_picture(spec, world, played, size) if pixels is None else None
    return {"size": size, "episodes": runs, "means": means, "still": still}


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
