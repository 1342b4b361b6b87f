"""A curriculum's favoured worlds, confirmed (issue 50 item 2, "the curricula's reports"): the buffer's highest scores
replayed on the confirmation stream, found (the buffer's score) beside confirmed in the report, resumable."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest

from killed_backend import DiesAfter
from worldagent import experiments
from worldagent.analysis.confirm import ConfirmedWorld, confirmation_keys, confirmation_seed
from worldagent.analysis.favoured import (
    SOURCE,
    confirm_favoured,
    favoured_line,
    favoured_picks,
    favoured_record,
    harder_count,
    read_favoured,
    stored_favoured,
)
from worldagent.events import parse_selection
from worldagent.reports.curriculum import favourites_table
from worldagent.search.campaign import stored_seed
from worldagent.search.objectives import search_keys
from worldagent.store import Evaluation, RunStore

REPEATS = 4


@pytest.fixture(scope="module")
def setup(racing_generator):
    """A scripted racing driver on the session's G(z) (racing declares a failure event: crash_rate > 0.5)."""
    return experiments.setup("racing", "driver", racing_generator, repeats=2)


def snapshot_of(latent_dim: int, held: int = 10, update: int = 96) -> dict:
    """A buffer snapshot as ``curricula.snapshots.save_snapshot`` writes one (scores all different)."""
    rng = np.random.default_rng(3)
    return {
        "update": np.int64(update),
        "z": rng.normal(size=(held, latent_dim)).astype(np.float32),
        "score": rng.permutation(held).astype(np.float32) / 10,
        "count": np.arange(1, held + 1),
        "age": np.arange(held)[::-1],
    }


def world(rank: int, crashed: list[int], digest: str | None = None) -> ConfirmedWorld:
    """A confirmed racing world whose fresh episodes crashed as ``crashed`` says."""
    pick = Evaluation(SOURCE, 96, rank, np.zeros(2, np.float32), 1.0 - rank / 10, [], 0.0, 0.0)
    episodes = [{"return": -280.0 if c else 60.0, "crashed": float(c)} for c in crashed]
    return ConfirmedWorld(pick, digest or f"{rank:032x}", episodes, rank)


def key_data(keys) -> set[tuple[int, ...]]:
    return {tuple(int(x) for x in row) for row in np.asarray(jax.random.key_data(keys)).reshape(len(keys), -1)}


def test_the_picks_are_the_buffers_highest_scores_best_first_with_where_they_came_from():
    snapshot = snapshot_of(3)
    picks = favoured_picks(snapshot, 4)
    slots = [p.slot for p in picks]
    assert [p.score for p in picks] == pytest.approx([0.9, 0.8, 0.7, 0.6])  # found: the buffer's own scores
    assert all(snapshot["score"][s] == pytest.approx(p.score) for s, p in zip(slots, picks))
    assert all(np.array_equal(p.latent, snapshot["z"][s]) for s, p in zip(slots, picks))
    assert {(p.campaign, p.generation) for p in picks} == {(SOURCE, 96)} and all(p.episodes == [] for p in picks)


def test_favoured_worlds_are_confirmed_on_fresh_keys_with_provenance_and_read_back(tmp_path, setup):
    snapshot = snapshot_of(setup.generator.latent_dim)
    with RunStore(tmp_path) as store:
        randoms = experiments.random_evaluation(store, setup, "return", worlds=4, seed=0, progress=False)
        found = confirm_favoured(store, setup, snapshot, curriculum="plr", score="learning potential", repeats=REPEATS, progress=False)
        rows = [(c.world, str(c.episodes)) for c in store.confirmations()]
        record = favoured_record(found, setup, curriculum="plr", score="learning potential", seed=0)
        again = stored_favoured(store, setup.spec, snapshot, record)  # what the report reads: no episode played
        searched = set()
        for campaign in store.campaigns():
            searched |= set().union(*(key_data(search_keys(stored_seed(campaign, e.generation, e.slot), len(e.episodes))) for e in randoms))
        selected = store.selections("curriculum:plr-favoured")
        assert [(c.world, str(c.episodes)) for c in store.confirmations()] == rows  # the read-back wrote nothing
    distinct = {c.digest for c in found}
    assert len(found) == 4 and all(c.repeats == REPEATS for c in found)
    assert [c.selected.score for c in found] == pytest.approx([0.9, 0.8, 0.7, 0.6])
    assert all(c.seed == confirmation_seed(0, c.digest) for c in found)  # the confirmation stream, not the run's seed
    fresh = set().union(*(key_data(confirmation_keys(c.seed, REPEATS)) for c in found))
    assert len(fresh) == REPEATS * len(distinct) and fresh.isdisjoint(searched) and len(searched) == 4 * 2
    # provenance: the buffer's score (what it means, over how many episodes), the snapshot's update and slot
    assert {(s.campaign, s.generation, s.metric) for s in selected} == {(SOURCE, 96, "learning potential")}
    by_slot = {c.selected.slot: c for c in found}
    assert len(selected) == len(distinct) and all(by_slot[s.slot].digest == s.world for s in selected)
    assert all(s.found == pytest.approx(by_slot[s.slot].selected.score) and s.found_episodes == snapshot["count"][s.slot] for s in selected)
    assert [(c.digest, c.episodes) for c in again] == [(c.digest, c.episodes) for c in found]
    assert record["update"] == 96 and record["confirmation"]["repeats"] == REPEATS and record["worlds"] == [c.digest for c in found]
    with RunStore(tmp_path) as store:
        assert stored_favoured(store, setup.spec, snapshot_of(setup.generator.latent_dim, update=128), record) == []  # another snapshot's
        shown = read_favoured(store, setup.spec, snapshot, record, randoms)
    crashes = [e["crashed"] for r in randoms for e in r.episodes]
    assert shown["baseline"] == pytest.approx(np.mean(crashes)) and shown["failure"].describe().startswith("crash_rate")
    assert [(c.digest, c.episodes) for c in shown["worlds"]] == [(c.digest, c.episodes) for c in found]


def test_a_killed_confirmation_of_favoured_worlds_resumes_to_the_rows_of_an_uninterrupted_one(tmp_path, setup, monkeypatch):
    from worldagent.analysis import confirm as module

    monkeypatch.setattr(module, "BATCH", 2)
    snapshot, rows = snapshot_of(setup.generator.latent_dim), {}
    arguments = {"curriculum": "accel", "score": "margin of target crash_rate > 0.5", "repeats": REPEATS, "progress": False}
    for name, backend in (("straight", None), ("killed", DiesAfter(1))):
        with RunStore(tmp_path / name) as store:
            if backend is not None:
                with pytest.raises(KeyboardInterrupt):
                    confirm_favoured(store, dataclasses.replace(setup, backend=backend), snapshot, **arguments)
                assert 0 < len(store.confirmations()) < 4
            confirm_favoured(store, setup, snapshot, **arguments)
            rows[name] = (sorted((c.world, c.seed, c.repeats, str(c.episodes)) for c in store.confirmations()), store.selections())
    assert rows["killed"] == rows["straight"] and len(rows["straight"][0]) > 1


def test_k_of_n_favoured_worlds_are_harder_than_average_on_the_lower_bound():
    failure = parse_selection("crash_rate > 0.5", "racing")
    hard = world(1, [1] * 16)  # crashes every fresh episode: interval [0.79, 1] above any baseline below it
    lucky = world(2, [1] * 2 + [0] * 14)  # crashes in 2 of 16: not beyond 0.1
    twin = world(3, [1] * 16, digest=hard.digest)  # a second latent G(z) repairs to the same world: one world
    assert harder_count([hard, lucky, twin, None], failure, 0.1) == (1, 2)
    line = favoured_line([hard, lucky, twin], "return", failure, 0.1)
    assert line.startswith("1 of 2 favoured worlds confirmed harder than average") and "0.1 on random worlds" in line
    assert "no random worlds" in favoured_line([hard], "return", failure, None)  # no baseline: pooled figures, no verdict
    assert "no failure event" in favoured_line([hard], "return", None, None)


def test_the_report_shows_found_beside_confirmed_and_the_verdict():
    snapshot = snapshot_of(2, held=6)
    failure = parse_selection("crash_rate > 0.5", "racing")
    worlds = [world(1, [1] * 16), world(2, [0] * 16), None, world(4, [1] * 2 + [0] * 14)]
    html = favourites_table(
        "racing", snapshot, {"worlds": worlds, "metric": "return", "failure": failure, "baseline": 0.1, "scored_by": "learning potential"}
    )
    assert "found: the buffer&#x27;s score (learning potential)" in html and "confirmed return [95%] (16 fresh episodes)" in html
    assert 'data-key="racing.curriculum.favoured1.score" data-value="0.5"' in html  # found: the buffer's top score
    assert 'data-key="racing.curriculum.favoured1.confirmed" data-value="-280.0"' in html  # confirmed: the fresh episodes' mean
    assert 'data-key="racing.curriculum.favoured2.failure_rate" data-value="0.0"' in html
    assert 'data-key="racing.curriculum.favoured3.confirmed" data-value="nan"' in html  # its row missing: n/a, not a number
    assert "data-key='racing.curriculum.harder' data-value='1' data-of='3'" in html and "1 of 3 favoured worlds confirmed harder" in html
    unconfirmed = favourites_table("racing", snapshot)
    assert "not confirmed on fresh episodes" in unconfirmed and "favoured1.confirmed" in unconfirmed and "harder" not in unconfirmed


def test_train_refuses_a_negative_confirm_in_one_line(tmp_path):
    from typer.testing import CliRunner

    from worldagent.cli import app

    result = CliRunner().invoke(app, ["train", "racing", "--curriculum", "plr", "--worlds", "vae", "--confirm", "-1", "--out", str(tmp_path / "x")])
    assert result.exit_code == 2 and "--confirm -1; pass a number of fresh episodes" in result.output and not (tmp_path / "x").exists()


@pytest.mark.slow  # trains a curriculum on racing (~1 min on 2 busy cores)
def test_train_with_a_curriculum_prints_how_many_favoured_worlds_are_confirmed_harder(
    tmp_path, racing_vae, racing_data, racing_generator, monkeypatch
):
    import json

    from typer.testing import CliRunner

    from worldagent.cli import app
    from worldagent.commands import train
    from worldagent.worlds.generator import save_generator

    monkeypatch.setattr(train, "BASELINE_WORLDS", 4)
    gen = save_generator(tmp_path / "gen", racing_vae, racing_data.save(tmp_path / "data.npz"), racing_generator)
    out = tmp_path / "run"
    args = ["train", "racing", "--curriculum", "plr", "--curriculum-set", "buffer_size=16", "--worlds", "vae", "--generator", str(gen)]
    args += ["--episodes", "32", "--confirm", str(REPEATS), "--out", str(out), "--quiet"]
    first = CliRunner().invoke(app, args)
    assert first.exit_code == 0, first.output
    line = next(text for text in first.output.splitlines() if "favoured worlds confirmed" in text)
    assert " of " in line and "harder than average (crash_rate" in line and "favoured.json" in line
    record = json.loads((out / "favoured.json").read_text())
    assert record["scored_by"] == "learning potential" and record["random_worlds"] == 4 and len(record["favoured"]) >= 1
    assert all(row["confirmed"]["return"]["episodes"] == REPEATS and "worse_than_random" in row for row in record["favoured"])
    with RunStore(out) as store:
        rows = [(c.world, str(c.episodes)) for c in store.confirmations()]
        assert {s.name for s in store.selections()} == {"curriculum:plr-favoured"}
    again = CliRunner().invoke(app, args)  # the run resumes finished; the confirmation is read back, not replayed
    assert again.exit_code == 0 and line in again.output
    with RunStore(out) as store:
        assert [(c.world, str(c.episodes)) for c in store.confirmations()] == rows
