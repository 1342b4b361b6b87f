"""Copy the report's figures that the documentation shows from a run of the main job into ``docs/images/``.

    worldagent reproduce --preset quick          # writes runs/quick/<env>/figures/*.png
    python docs/gen_images.py runs/quick         # refreshes docs/images/report-*.png

The explorer's screenshots come from its browser test instead (``docs/explorer.md``, "At a glance").
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

IMAGES = Path(__file__).resolve().parent / "images"
# docs/images/<name> <- <run>/<env>/figures/<figure>
FIGURES = {
    "report-comparison-racing.png": ("racing", "comparison.png"),
    "report-atlas-racing.png": ("racing", "atlas.png"),
    "report-influence-harvest.png": ("harvest", "influence.png"),
}


def copy_figures(run_dir: Path, images: Path = IMAGES) -> list[Path]:
    """Copy each of ``FIGURES`` from ``run_dir`` into ``images``; a missing figure stops with the command that makes it."""
    sources = {name: run_dir / env / "figures" / figure for name, (env, figure) in FIGURES.items()}
    missing = [str(path) for path in sources.values() if not path.is_file()]
    if missing:
        raise SystemExit(f"missing {', '.join(missing)}: run `worldagent reproduce --preset quick --out {run_dir}` first")
    return [Path(shutil.copyfile(source, images / name)) for name, source in sources.items()]


if __name__ == "__main__":
    for path in copy_figures(Path(sys.argv[1] if len(sys.argv) > 1 else "runs/quick")):
        print(path)
