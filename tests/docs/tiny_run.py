"""A tiny run directory laid out as ``runs/quick`` (racing only), for the documentation's blocks to run on.

Built with the commands the pages teach, in-process and at toy budgets (a minute on 2 cores, where
``reproduce --preset tiny`` takes three): a dataset, a generator G(z) trained for one epoch, an agent trained
for 16 episodes, and in ``racing/store.sqlite`` a random evaluation and an atlas.
The influence phase's two agents are copies of that agent (``diff`` of an agent against itself still runs
every step). Its numbers mean nothing; the blocks check that the examples run and print what the pages show.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from block_runner import run_worldagent
from doc_blocks import cut_budgets

FAILURE = "crash_rate > 0.5"


def build_tiny_run(run: Path) -> Path:
    """Write the tiny run into ``run`` (racing's phases only); returns ``run``."""
    racing = run / "racing"
    agent, generator = racing / "agent", racing / "generator"
    common = ["--agent", str(agent), "--generator", str(generator)]
    run_worldagent(["dataset", "racing", "--n", "128", "--out", str(racing / "dataset.npz"), "--quiet"])
    run_worldagent(
        [
            "generator",
            "train",
            "racing",
            "--dataset",
            str(racing / "dataset.npz"),
            "--epochs",
            "1",
            "--batch-size",
            "32",
            "--out",
            str(generator),
            "--quiet",
        ]
    )
    run_worldagent(["train", "racing", "--episodes", "16", "--out", str(agent), "--quiet"])
    for name in ("default-s0", "influenced-s0"):
        shutil.copytree(agent, racing / "influence" / "agents" / name)
    run_worldagent(["evaluate", "random", "racing", *common, "--worlds", "8", "--repeats", "2", "--out", str(racing), "--quiet"])
    atlas = ["atlas", "racing", *common, "--budget", "21", "--failure", FAILURE, "--no-explain", "--out", str(racing), "--quiet"]
    run_worldagent(cut_budgets(atlas))  # at the sizes the blocks' atlases run at
    return run
