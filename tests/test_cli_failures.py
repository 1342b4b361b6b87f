"""The last bad inputs and machine failures that still crashed (issue 41): each is one line that names the fix.

A store another process is writing, a full disk while writing a dataset or a checkpoint (no temp file left
behind), a campaign resumed with another --repeats, a picture asked for as .txt, and Ctrl-C in train.
"""

from __future__ import annotations

import errno
import sqlite3

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from worldagent.cli import app
from worldagent.commands.console import friendly_errors
from worldagent.errors import WorldagentError
from worldagent.files import write_atomically
from worldagent.search.campaign import CampaignSpec, Outcome, run_campaign
from worldagent.search.optimisers import OptimiserConfig
from worldagent.store import RunStore


def one_line(result) -> str:
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in result.output, result.output
    return lines[0]


def full_disk(tmp):
    """A save that writes half its file, then finds the disk full."""
    tmp.write_bytes(b"half a file")
    raise OSError(errno.ENOSPC, "No space left on device")


def test_a_failed_save_leaves_neither_the_file_nor_its_temp(tmp_path):
    target = tmp_path / "kept.npz"
    target.write_bytes(b"the old one")
    with pytest.raises(OSError):
        write_atomically(target, full_disk)
    assert target.read_bytes() == b"the old one" and [p.name for p in tmp_path.iterdir()] == ["kept.npz"]


def test_a_full_disk_in_dataset_is_one_line_and_leaves_no_temp(tmp_path, monkeypatch):
    import worldagent.worlds.dataset as dataset_module

    monkeypatch.setattr(dataset_module.np, "savez_compressed", lambda handle, **arrays: (handle.write(b"half"), full_disk(tmp_path / "x"))[1])
    result = CliRunner().invoke(app, ["dataset", "racing", "--n", "4", "--out", str(tmp_path / "d.npz"), "--quiet"])
    assert result.exit_code == 2
    assert "no space left on the device" in one_line(result) and "run the same command again" in result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x"]  # x: the fake's own write; no .d.npz.*.tmp, no d.npz


def store_app(path) -> typer.Typer:
    """A command that writes a campaign into the store at ``path`` (what atlas, search, evaluate do first)."""
    command = typer.Typer()

    @command.command()
    @friendly_errors
    def write() -> None:
        with RunStore(path) as store:
            store.open_campaign("c", "racing", "return", False, "random", 1, 0, {}, resume=True)

    return command


def test_a_store_another_process_is_writing_is_one_line(tmp_path, monkeypatch):
    path = tmp_path / "store.sqlite"
    RunStore(path).close()
    monkeypatch.setattr("worldagent.store.BUSY_SECONDS", 0.2)
    other = sqlite3.connect(path, isolation_level=None)
    other.execute("BEGIN EXCLUSIVE")  # another command in the middle of a write
    try:
        result = CliRunner().invoke(store_app(path), [])
    finally:
        other.execute("ROLLBACK")
        other.close()
    assert result.exit_code == 2
    line = one_line(result)
    assert "locked by another process" in line and "another --out" in line


def test_other_os_errors_still_show_their_traceback():
    command = typer.Typer()

    @command.command()
    @friendly_errors
    def broken() -> None:
        raise OSError(errno.EIO, "input/output error")

    result = CliRunner().invoke(command, [])
    assert isinstance(result.exception, OSError)  # a bug or a broken disk: not hidden behind a line


class Played:
    """An objective whose worlds are played ``repeats`` times (``LatentObjective`` keeps it as ``repeats``)."""

    def __init__(self, repeats: int):
        self.repeats = repeats

    def __call__(self, z, seeds):
        return [Outcome(float(np.sum(latent**2)), [{"cost": float(np.sum(latent**2))}] * self.repeats) for latent in z]


def test_a_campaign_resumed_with_other_repeats_is_refused(tmp_path):
    spec = CampaignSpec(name="atlas-min-return-s0", env="racing", objective="cost", maximize=False, optimiser="random", budget=5, seed=0, dim=3)
    spec = spec.__class__(**{**spec.__dict__, "config": OptimiserConfig(random_batch=5)})
    with RunStore(tmp_path) as store:
        run_campaign(store, spec, Played(2), progress=False)
        again = spec.__class__(**{**spec.__dict__, "budget": 10})
        with pytest.raises(WorldagentError, match=r"played each world 2 times, not --repeats 1; pass --repeats 2 to resume it"):
            run_campaign(store, again, Played(1), resume=True, progress=False)
        assert len(run_campaign(store, again, Played(2), resume=True, progress=False)) == 10  # the same repeats resume


def test_worlds_refuses_a_picture_in_a_text_file(tmp_path):
    result = CliRunner().invoke(app, ["worlds", "racing", "--n", "2", "--out", str(tmp_path / "w.txt")])
    assert result.exit_code == 2 and "--out" in one_line(result) and "w.png" in result.output
    assert list(tmp_path.iterdir()) == []


def test_ctrl_c_in_train_says_where_the_checkpoint_is(tmp_path, monkeypatch):
    out = tmp_path / "run"

    def interrupted(*args, **kwargs):
        out.mkdir(parents=True, exist_ok=True)
        (out / "checkpoint.msgpack").write_bytes(b"state")  # the driver checkpoints on its way out
        raise KeyboardInterrupt

    monkeypatch.setattr("worldagent.agents.training.train", interrupted)
    monkeypatch.setattr("worldagent.agents.distributions.world_distribution", lambda *args, **kwargs: None)  # no worlds drawn: the run stops at once
    monkeypatch.setattr("worldagent.curricula.make_curriculum", lambda *args, **kwargs: None)
    monkeypatch.setattr("worldagent.curricula.late_replay_warning", lambda *args: None)
    result = CliRunner().invoke(app, ["train", "racing", "--out", str(out), "--episodes", "10", "--quiet"])
    assert result.exit_code == 130
    line = one_line(result)
    assert str(out / "checkpoint.msgpack") in line and "run the same command again to resume" in line


def test_the_learning_curve_reads_updates_as_whole_numbers(tmp_path):
    from worldagent.agents.training import _write_curve, read_curve

    (tmp_path / "old.csv").write_text("update,wall_seconds,return\n1.0,0.5,-3.0\n2.0,1.0,-2.0\n")  # files written before the fix
    assert [row["update"] for row in read_curve(tmp_path / "old.csv")] == [1, 2]
    _write_curve(tmp_path / "curve.csv", read_curve(tmp_path / "old.csv"))
    assert (tmp_path / "curve.csv").read_text().splitlines()[1].startswith("1,0.5,")


def test_a_full_disk_in_train_is_one_line_and_leaves_no_temp_checkpoint(tmp_path, monkeypatch):
    from worldagent.files import write_bytes

    out = tmp_path / "run"

    def checkpoint_on_a_full_disk(*args, **kwargs):
        write_atomically(out / "checkpoint.msgpack", full_disk)  # what the driver's checkpoint does when the disk fills
        write_bytes(out / "never.msgpack", b"")

    monkeypatch.setattr("worldagent.agents.training.train", checkpoint_on_a_full_disk)
    monkeypatch.setattr("worldagent.agents.distributions.world_distribution", lambda *args, **kwargs: None)
    monkeypatch.setattr("worldagent.curricula.make_curriculum", lambda *args, **kwargs: None)
    monkeypatch.setattr("worldagent.curricula.late_replay_warning", lambda *args: None)
    result = CliRunner().invoke(app, ["train", "racing", "--out", str(out), "--episodes", "10", "--quiet"])
    assert result.exit_code == 2 and "no space left on the device" in one_line(result)
    assert list(out.iterdir()) == []  # no .checkpoint.msgpack.*.tmp
