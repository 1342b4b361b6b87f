"""Bad input to the commands fails with one line naming the fix, before anything heavy loads (issue 30, item 7).

Every case passes a generator directory that does not exist: a check that ran only after the
agent and generator loaded would answer "holds no generator" instead of the expected line.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from damaged_store import damage_evaluations, store_with_a_campaign
from worldagent.cli import app
from worldagent.files import can_create_files_in

runner = CliRunner()

HEAVY = ["--agent", "driver", "--generator", "no-generator-here"]  # never loaded when a check fails first
TRAIN_HEAVY = ["--worlds", "vae", "--generator", "no-generator-here"]  # train's worlds: never loaded when a check fails first
INFLUENCE = ["influence", "racing", *HEAVY, "--select", "crash_rate > 0.5"]
REPRODUCE = ["reproduce", "--preset", "tiny", "--env", "racing"]


def one_line(result) -> str:
    """The single ``error:`` line of a refused command (exit code 2), or a failure showing what came instead."""
    lines = result.output.strip().splitlines()
    assert result.exit_code == 2 and len(lines) == 1 and lines[0].startswith("error:"), result.output
    return lines[0]


@pytest.fixture
def paths(tmp_path):
    """``file``: an existing file; ``dir``: an existing folder; ``new``: a folder not made yet."""
    (tmp_path / "file").write_text("x")
    (tmp_path / "dir").mkdir()
    return {name: str(tmp_path / name) for name in ("file", "dir", "new")}


def cases(p: dict) -> list[tuple[list[str], str]]:
    """(arguments, a piece of the one line they must get)."""
    under_file = f"{p['file']}/out"
    return [
        # unwritable outputs
        (["worlds", "racing", "--out", f"{under_file}.png"], "is a file, not a folder"),
        (["worlds", "racing", "--out", p["dir"]], "is a folder; pass a file name"),
        (["play", "racing", "--policy", "driver", "--out", f"{under_file}.png"], "is a file, not a folder"),
        (["dataset", "racing", "--n", "4", "--out", f"{under_file}.npz"], "is a file, not a folder"),
        (["dataset", "racing", "--n", "4", "--out", p["dir"]], "is a folder; pass a file name"),
        (["atlas", "racing", *HEAVY, "--out", p["file"]], "is a file; pass a folder"),
        (["atlas", "racing", *HEAVY, "--out", under_file], "is a file, not a folder"),
        (["search", "racing", *HEAVY, "--out", p["file"]], "is a file; pass a folder"),
        (["evaluate", "random", "racing", *HEAVY, "--out", under_file], "is a file, not a folder"),
        (["strategic", "racing", *HEAVY, "--out", p["file"]], "is a file; pass a folder"),
        (["compare", "racing", *HEAVY, "--out", p["file"]], "is a file; pass a folder"),
        (["generator", "train", "racing", "--out", p["file"]], "is a file; pass a folder"),
        (["generator", "show", "no-generator-here", "--out", p["file"]], "is a file; pass a folder"),
        (["train", "racing", *TRAIN_HEAVY, "--out", p["file"]], "--out {file} is a file; pass a folder"),
        (["train", "racing", *TRAIN_HEAVY, "--out", under_file], "is a file, not a folder"),
        ([*INFLUENCE, "--out", p["file"]], "is a file; pass a folder"),
        ([*INFLUENCE, "--out", under_file], "is a file, not a folder"),
        ([*REPRODUCE, "--out", p["file"]], "is a file; pass a folder"),
        ([*REPRODUCE, "--out", under_file], "is a file, not a folder"),
        (["report", p["file"]], "RUN_DIR {file} is a file; pass a folder"),
        (["report", under_file], "is a file, not a folder; choose another RUN_DIR"),
        # seeds
        (["worlds", "racing", "--seed", "-1", "--out", f"{p['dir']}/w.png"], "--seed is -1; seeds are integers from 0"),
        (["play", "racing", "--policy", "driver", "--seed", "-1", "--out", f"{p['dir']}/e.png"], "--seed is -1"),
        (["dataset", "racing", "--seed", "99999999999999999999", "--out", f"{p['dir']}/d.npz"], "seeds are integers from 0 to 2,147,483,647"),
        (["atlas", "racing", *HEAVY, "--seed", "-1", "--out", p["new"]], "--seed is -1"),
        (["search", "racing", *HEAVY, "--seed", "-1", "--out", p["new"]], "--seed is -1"),
        (["evaluate", "random", "racing", *HEAVY, "--seed", "-1", "--out", p["new"]], "--seed is -1"),
        (["strategic", "racing", *HEAVY, "--seed", "-1", "--out", p["new"]], "--seed is -1"),
        (["compare", "racing", *HEAVY, "--random-seed", "-5", "--out", p["new"]], "--random-seed is -5"),
        (["generator", "train", "racing", "--seed", "-1", "--out", p["new"]], "--seed is -1"),
        (["generator", "report", "no-generator-here", "--seed", "-1"], "--seed is -1"),
        (["train", "racing", *TRAIN_HEAVY, "--seed", "-1", "--out", p["new"]], "--seed is -1"),
        (["train", "racing", *TRAIN_HEAVY, "--seed", "99999999999", "--out", p["new"]], "seeds are integers from 0 to 2,147,483,647"),
        ([*INFLUENCE, "--seed", "-1", "--out", p["new"]], "--seed is -1"),
        # sizes
        (["worlds", "racing", "--n", "200000", "--out", f"{p['dir']}/w.png"], "--n is 200,000, above the cap of 256"),
        (["play", "racing", "--policy", "driver", "--episodes", "100000", "--out", f"{p['dir']}/e.png"], "above the cap of 256"),
        (["dataset", "racing", "--n", "1000000000", "--out", f"{p['dir']}/d.npz"], "above the cap of 1,000,000"),
        (["generator", "train", "racing", "--n", "1000000000", "--out", p["new"]], "above the cap of 1,000,000"),
        (["generator", "show", "no-generator-here", "--count", "100000"], "--count is 100,000, above the cap"),
        (["generator", "report", "no-generator-here", "--samples", "0"], "--samples is 0; it must be at least 1"),
        (["evaluate", "random", "racing", *HEAVY, "--repeats", "100000000", "--out", p["new"]], "--repeats is 100,000,000, above the cap of 1,000"),
        (["search", "racing", *HEAVY, "--budget", "0", "--out", p["new"]], "--budget is 0"),
        (["strategic", "racing", *HEAVY, "--random-worlds", "100000000", "--out", p["new"]], "--random-worlds is 100,000,000, above the cap"),
        (["compare", "racing", *HEAVY, "--seeds", "5000", "--out", p["new"]], "--seeds is 5,000, above the cap of 1,000"),
        (["train", "racing", *TRAIN_HEAVY, "--episodes", "0", "--out", p["new"]], "--episodes is 0; it must be at least 1"),
        (["train", "racing", *TRAIN_HEAVY, "--episodes", "1000000000000", "--out", p["new"]], "--episodes is 1,000,000,000,000, above the cap"),
        ([*INFLUENCE, "--episodes", "1000000000000", "--out", p["new"]], "--episodes is 1,000,000,000,000, above the cap"),
        ([*INFLUENCE, "--seeds", "0", "--out", p["new"]], "--seeds is 0; it must be at least 1"),
        ([*INFLUENCE, "--candidates", "0", "--out", p["new"]], "--candidates is 0; it must be at least 1"),
        ([*INFLUENCE, "--eval-worlds", "100000000", "--out", p["new"]], "--eval-worlds is 100,000,000, above the cap"),
        ([*INFLUENCE, "--repeats", "100000000", "--out", p["new"]], "--repeats is 100,000,000, above the cap of 1,000"),
        ([*INFLUENCE, "--search-budget", "-1", "--out", p["new"]], "--search-budget is -1; pass 0 (no search) or more"),
        ([*INFLUENCE, "--search-budget", "100000000", "--out", p["new"]], "--search-budget is 100,000,000, above the cap"),
        ([*INFLUENCE, "--search", "annealing", "--out", p["new"]], "unknown --search 'annealing'; use one of: cmaes, atlas"),
        ([*REPRODUCE, "--restart", "everything", "--out", p["new"]], "unknown phase 'everything'"),
        # options, descriptors and failure events, checked before the agent and generator load
        (["atlas", "racing", *HEAVY, "--budget", "0", "--out", p["new"]], "--budget is 0"),
        (["atlas", "racing", *HEAVY, "--descriptors", "wingspan", "--out", p["new"]], "unknown descriptor 'wingspan' for racing"),
        (["atlas", "racing", *HEAVY, "--cells", "1", "--out", p["new"]], "--cells 1"),
        (["atlas", "racing", *HEAVY, "--failure", "bogus", "--out", p["new"]], "expected an operator"),
        (["atlas", "racing", *HEAVY, "--failure", "wingspan > 2", "--out", p["new"]], "wingspan"),
        (["atlas", "racing", *HEAVY, "--objective", "speed", "--out", p["new"]], "racing has no metric 'speed'"),
        (["search", "racing", *HEAVY, "--optimiser", "annealing", "--out", p["new"]], "unknown optimiser 'annealing'"),
        (["search", "racing", *HEAVY, "--objective", "speed", "--out", p["new"]], "racing has no metric 'speed'"),
        (["evaluate", "random", "racing", *HEAVY, "--metric", "speed", "--out", p["new"]], "racing has no metric 'speed'"),
        (["strategic", "racing", *HEAVY, "--optimiser", "annealing", "--out", p["new"]], "unknown optimiser 'annealing'"),
        (["compare", "racing", *HEAVY, "--metric", "speed", "--out", p["new"]], "racing has no metric 'speed'"),
    ]


def test_bad_input_gets_one_line_before_anything_loads(paths):
    for args, message in cases(paths):
        line = one_line(runner.invoke(app, args))
        assert message.format(**paths) in line, (args, line)
    assert not Path(paths["new"]).exists() and not any(Path(paths["dir"]).iterdir()), "a refused command wrote something"


def damaged_store(folder):
    """A run store in ``folder`` (campaign "c") whose evaluations table is damaged; ``folder``."""
    damage_evaluations(store_with_a_campaign(folder))
    return folder


def test_a_damaged_store_is_refused_before_anything_loads(tmp_path):
    from worldagent.commands.reproduce import check_reproduce_dir

    run = damaged_store(tmp_path / "run")
    commands = [[name, "racing", *HEAVY] for name in ("search", "atlas", "strategic", "compare")]
    failure_rate = ["failure-rate", "racing", *HEAVY, "--event", "crash_rate > 0.5"]
    for command in (*commands, failure_rate, ["evaluate", "random", "racing", *HEAVY], INFLUENCE):
        line = one_line(runner.invoke(app, [*command, "--out", str(run)]))
        assert "store.sqlite is damaged" in line and "restore it from a copy" in line
    # a reproduce run directory keeps one store an environment; the report reads them all
    damaged_store(tmp_path / "reproduce" / "racing")
    for command in ([*REPRODUCE, "--out", str(tmp_path / "reproduce")], ["report", str(tmp_path / "reproduce")]):
        line = one_line(runner.invoke(app, command))
        assert f"{tmp_path / 'reproduce' / 'racing' / 'store.sqlite'} is damaged" in line and "restore it from a copy" in line
    check_reproduce_dir(tmp_path / "reproduce", ["racing"], ["random", "strategic"])  # redoing random deletes the store: no refusal


@pytest.fixture
def read_only(tmp_path):
    """A folder this process cannot create files in (skipped where permissions do not bind, e.g. as root)."""
    folder = tmp_path / "read-only"
    folder.mkdir()
    folder.chmod(0o555)
    if can_create_files_in(folder):
        folder.chmod(0o755)
        pytest.skip("permissions do not stop this user (root?)")
    yield folder
    folder.chmod(0o755)


def test_read_only_outputs_and_stores(read_only):
    from worldagent.errors import WorldagentError
    from worldagent.store import RunStore

    line = one_line(runner.invoke(app, ["worlds", "racing", "--out", str(read_only / "w.png")]))
    assert f"cannot create files in {read_only}" in line
    for command in (
        ["search", "racing", *HEAVY, "--out"],
        ["train", "racing", *TRAIN_HEAVY, "--out"],
        [*INFLUENCE, "--out"],
        [*REPRODUCE, "--out"],
        ["report"],
    ):
        for run in (read_only, read_only / "run"):
            line = one_line(runner.invoke(app, [*command, str(run)]))
            assert f"cannot create files in {read_only}" in line, (command, line)
    locked = read_only.parent / "locked"
    (locked / "inner").mkdir(parents=True)
    locked.chmod(0o000)  # not even readable: nothing inside it can be looked at
    try:
        line = one_line(runner.invoke(app, ["dataset", "racing", "--out", str(locked / "inner" / "d.npz")]))
        assert f"cannot create files in {locked}" in line
    finally:
        locked.chmod(0o755)
    writable = read_only.parent / "run"
    with RunStore(writable):
        pass
    (writable / "store.sqlite").chmod(0o444)
    line = one_line(runner.invoke(app, ["atlas", "racing", *HEAVY, "--out", str(writable)]))
    assert "store.sqlite is read-only; make it writable" in line
    # a valid store in a read-only folder is named as such, not "not a worldagent run store"
    read_only.chmod(0o755)
    with RunStore(read_only):
        pass
    read_only.chmod(0o555)
    with pytest.raises(WorldagentError, match="SQLite writes the store and files beside it in .*; make both writable"):
        RunStore(read_only, create=False)


def test_repair_settings_are_refused_before_the_vae_trains(tmp_path):
    out = tmp_path / "gen"
    line = one_line(runner.invoke(app, ["generator", "train", "racing", "--out", str(out), "--n", "8", "--repair", "apples=40", "--quiet"]))
    assert "nearest-world repair of racing has no settings (given: apples); drop --repair" in line
    assert (out / "dataset.npz").exists() and sorted(p.name for p in out.iterdir()) == ["dataset.npz"]  # no VAE checkpoint
    out = tmp_path / "harvest"
    line = one_line(runner.invoke(app, ["generator", "train", "harvest", "--out", str(out), "--n", "8", "--repair", "apples=many", "--quiet"]))
    assert "harvest's repair refuses its settings (apples='many')" in line and "fix or drop --repair" in line
    assert sorted(p.name for p in out.iterdir()) == ["dataset.npz"]
    out = tmp_path / "named"
    line = one_line(runner.invoke(app, ["generator", "train", "racing", "--out", str(out), "--n", "8", "--repair", "closest", "--quiet"]))
    assert "racing has no repair 'closest'; use one of: nearest, open" in line and not out.exists()
    line = one_line(runner.invoke(app, ["generator", "train", "racing", "--out", str(out), "--repair", "open", "--repair", "nearest", "--quiet"]))
    assert "name one repair (e.g. --repair open)" in line and not out.exists()


def test_envs_lists_descriptors_failure_and_presets():
    result = runner.invoke(app, ["envs"])
    assert result.exit_code == 0, result.output
    text = result.output
    assert "descriptors: total_curvature (default), sharpest_corner (default), track_length (for atlas --descriptors)" in text
    assert "wall_share (default)" in text and "apple_clustering (default)" in text and "largest_patch" in text
    assert "failure:     crash_rate > 0.5" in text
    assert "presets:     paper (10,000 worlds, 10,000 episodes)" in text and "tiny (256 worlds, 4 episodes)" in text
    assert "repairs:     nearest (default): Repair by the nearest dataset world; open: New valid tracks" in text


def help_text(*command: str) -> str:
    """``--help`` of a command as one line of words (rich's box and wrapping removed)."""
    return " ".join(runner.invoke(app, [*command, "--help"]).output.replace("│", " ").split())


def test_help_texts_name_every_phase_and_where_descriptors_are_listed():
    from worldagent.reproduce.presets import PHASES

    assert "atlas" in PHASES
    assert f"Redo this phase (and what depends on it): {', '.join(PHASES)}." in help_text("reproduce")
    assert "`worldagent envs` lists" in help_text("atlas")
