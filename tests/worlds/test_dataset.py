"""Datasets of worlds: round trip, and clear refusals of bad files."""

from __future__ import annotations

import numpy as np
import pytest

from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.worlds.dataset import FORMAT_VERSION, WorldDataset, make_dataset


@pytest.mark.parametrize("env", ["racing", "harvest"])
def test_round_trip_is_exact(tmp_path, env, racing_data, harvest_data):
    data = racing_data if env == "racing" else harvest_data
    loaded = WorldDataset.load(data.save(tmp_path / "d.npz"), env=env)
    assert loaded.env == env and loaded.fingerprint == data.fingerprint
    np.testing.assert_array_equal(loaded.seeds, data.seeds)
    np.testing.assert_array_equal(loaded.cells, data.cells)
    for name in vars(data.worlds):
        np.testing.assert_array_equal(getattr(loaded.worlds, name), getattr(data.worlds, name))


def test_worlds_are_the_generators_and_deterministic(racing_data):
    again = make_dataset(registry.get("racing"), 4, 0, progress=False)  # a spec works as well as a name
    assert again.env == "racing" and again.cell_shape == registry.get("racing").cell_shape
    np.testing.assert_array_equal(again.cells, racing_data.cells[:4])
    assert racing_data.cells.shape == (256, 64 * 64) and racing_data.cells.dtype == np.uint8
    np.testing.assert_array_equal(registry.get("racing").cells(again.worlds), again.cells)


def _rewrite(path, tmp_path, **changes):
    with np.load(path, allow_pickle=False) as data:
        arrays = {name: data[name] for name in data.files}
    arrays.update(changes)
    out = tmp_path / "changed.npz"
    np.savez(out, **arrays)
    return out


def test_bad_files_are_refused_with_a_clear_message(tmp_path, racing_data):
    good = racing_data.subset(np.arange(8)).save(tmp_path / "good.npz")
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(good.read_bytes()[:200])
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a dataset at all")
    cases = [
        (truncated, "corrupted"),
        (garbage, "corrupted"),
        (tmp_path / "missing.npz", "does not exist"),
        (_rewrite(good, tmp_path, format_version=np.int64(FORMAT_VERSION + 1)), "format version"),
    ]
    for path, message in cases:
        with pytest.raises(WorldagentError, match=message) as error:
            WorldDataset.load(path)
        assert "\n" not in str(error.value) and "worldagent dataset" in str(error.value)
    with pytest.raises(WorldagentError, match="not harvest worlds"):
        WorldDataset.load(good, env=registry.get("harvest"))
    with pytest.raises(WorldagentError, match="unknown environment 'chess'") as error:
        WorldDataset.load(_rewrite(good, tmp_path, env=np.str_("chess")))
    assert str(error.value).startswith(f"dataset file {tmp_path}") and "\n" not in str(error.value)
    with pytest.raises(WorldagentError, match="unknown environment 'chess'"):
        WorldDataset.load(good, env="chess")
    flipped = racing_data.cells[:8].copy()
    flipped[0, 0] ^= 1
    with pytest.raises(WorldagentError, match="do not match"):
        WorldDataset.load(_rewrite(good, tmp_path, cells=flipped))
    with pytest.raises(WorldagentError, match="inconsistent"):
        WorldDataset.load(_rewrite(good, tmp_path, seeds=np.arange(5)))
    with np.load(good, allow_pickle=False) as data:  # a well-formed file of no worlds: every per-world array empty
        empty = {name: data[name][:0] for name in data.files if name in ("seeds", "cells") or name.startswith("world/")}
    with pytest.raises(WorldagentError, match="holds no worlds"):
        WorldDataset.load(_rewrite(good, tmp_path, **empty))


def test_bad_requests_are_refused():
    for env, n, seed, message in (("chess", 4, 0, "unknown environment"), ("racing", 0, 0, "at least 1"), ("racing", 4, -1, "non-negative")):
        with pytest.raises(WorldagentError, match=message):
            make_dataset(env, n, seed, progress=False)
