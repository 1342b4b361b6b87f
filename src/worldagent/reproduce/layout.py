"""Where a ``reproduce`` run directory keeps each environment's outputs (phases and the report read it).

Layout of ``<run>/<env>/``::

    dataset.npz            the procedurally generated worlds (paper §5.2.1)
    generator/             the VAE and G(z) (quality.json: its quality figures)
    agent/                 the training run (checkpoint, curve.csv/png, the saved agent in policy/)
    store.sqlite           random / strategic (min, max) / comparison / atlas / failure-rate campaigns
    influence/             the influencing experiment (influence.json, its agents)
    figures/               figures drawn by phases (strategic.png, comparison.png, influence.png, atlas.png, ...)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class RunLayout:
    """The paths of one environment's part of a run directory.

    Attributes:
        run_dir: the run directory.
        env: the registered environment's name.
    """

    run_dir: Path
    env: str

    @property
    def dir(self) -> Path:
        return Path(self.run_dir) / self.env

    @property
    def dataset_path(self) -> Path:
        return self.dir / "dataset.npz"

    @property
    def generator_dir(self) -> Path:
        return self.dir / "generator"

    @property
    def quality_path(self) -> Path:
        return self.generator_dir / "quality.json"

    @property
    def agent_dir(self) -> Path:
        return self.dir / "agent"

    @property
    def store_path(self) -> Path:
        return self.dir / "store.sqlite"

    @property
    def influence_dir(self) -> Path:
        return self.dir / "influence"

    @property
    def influence_result(self) -> Path:
        return self.influence_dir / "influence.json"

    @property
    def figures(self) -> Path:
        return self.dir / "figures"

    def figure(self, name: str) -> Path:
        """``figures/<name>.png`` (traversals, random, strategic, comparison, influence)."""
        return self.figures / f"{name}.png"

    def rel(self, path: Path) -> str:
        """``path`` relative to the run directory (the run directory may be moved)."""
        return str(Path(path).relative_to(self.run_dir))

    def phase_outputs(self) -> dict[str, list[Path]]:
        """The files and folders each phase writes (removed when ``--restart`` redoes it)."""
        return {
            "dataset": [self.dataset_path],
            "generator": [self.generator_dir, self.figure("generator_traversals")],
            "agent": [self.agent_dir],
            "strategic": [self.figure("strategic")],
            "compare": [self.figure("comparison")],
            "influence": [self.influence_dir, self.figure("influence")],
            "atlas": [self.figure("atlas"), self.figure("atlas_counterfactuals")],
        }
