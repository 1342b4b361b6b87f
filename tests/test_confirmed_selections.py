"""Strategic, search and the optimiser comparison confirm the worlds they report (issue 50 items 2 and 3):
found (the selection's figure) beside confirmed (fresh episodes from keys no search drew), stored and read back."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest
from typer.testing import CliRunner

import toy_env
from worldagent import experiments
from worldagent.analysis.confirm import ConfirmedWorld, confirmation_keys
from worldagent.cli import app
from worldagent.reports.comparison import confirmed_efficiency, ordering
from worldagent.reports.strategic import winners_curse
from worldagent.search.campaign import stored_seed
from worldagent.search.objectives import search_keys
from worldagent.search.optimisers import OptimiserConfig
from worldagent.store import Evaluation, RunStore

SMALL = OptimiserConfig(popsize=4, bo_batch=2, random_batch=4)
AGENT = "random"  # the toy's uniform policy: its episodes differ, so a found score is partly luck
runner = CliRunner()


@pytest.fixture(scope="module")
def toy():
    with toy_env.registered() as spec:
        yield spec


@pytest.fixture(scope="module")
def generator_dir(toy, tmp_path_factory):
    """A tiny toy generator, saved (the commands load it from its directory)."""
    from worldagent.worlds.dataset import make_dataset
    from worldagent.worlds.generator import build_generator, save_generator
    from worldagent.worlds.vae import VAEConfig, train_vae

    where = tmp_path_factory.mktemp("toy-generator")
    dataset = make_dataset(toy.name, 64, 0, progress=False)
    path = dataset.save(where / "dataset.npz")
    vae = train_vae(dataset, VAEConfig(encoder=(32,), decoder=(32,), epochs=1, batch_size=32, warmup_epochs=1), progress=False)
    return save_generator(where / "generator", vae, path, build_generator(vae, dataset))


@pytest.fixture(scope="module")
def setup(toy, generator_dir):
    return experiments.setup(toy.name, AGENT, str(generator_dir), repeats=2)


def key_data(keys) -> set[tuple[int, ...]]:
    return {tuple(int(x) for x in row) for row in np.asarray(jax.random.key_data(keys)).reshape(len(keys), -1)}


def searched_keys(store: RunStore) -> set[tuple[int, ...]]:
    """Every episode key any campaign of ``store`` played."""
    found = set()
    for campaign in store.campaigns():
        for e in store.evaluations(campaign.name):
            found |= key_data(search_keys(stored_seed(campaign, e.generation, e.slot), len(e.episodes)))
    return found


def fresh_keys(confirmed) -> set[tuple[int, ...]]:
    return set().union(*(key_data(confirmation_keys(c.seed, c.repeats)) for c in confirmed))


def rows_of(store: RunStore) -> tuple:
    """What a rerun must leave alone: every evaluation's and confirmation's row."""
    return sorted(e.finished for e in store.evaluations()), [(c.world, str(c.episodes)) for c in store.confirmations()]


COMPARE = {"maximize": False, "optimisers": ("cmaes", "random"), "budget": 4, "seeds": (0, 1), "progress": False}


@pytest.fixture(scope="module")
def confirmed_run(setup, tmp_path_factory):
    """A store with random worlds, a strategic evaluation and a comparison, each reported world confirmed on 8 fresh episodes
    (one episode count: one compile)."""
    path = tmp_path_factory.mktemp("confirmed") / "store.sqlite"
    with RunStore(path) as store:
        experiments.random_evaluation(store, setup, "return", worlds=4, seed=1, progress=False)
        strategic = experiments.strategic_evaluation(store, setup, "return", budget=8, seed=1, progress=False, config=SMALL, confirm=8)
        runs = experiments.compare_optimisers(store, setup, "return", config=SMALL, **COMPARE)
        confirmed = experiments.confirm_optimisers(store, setup, "return", repeats=8, **COMPARE)
    return {"path": path, "strategic": strategic, "runs": runs, "confirmed": confirmed}


def test_strategic_confirms_both_worlds_on_keys_no_search_drew_and_a_rerun_reads_them_back(setup, confirmed_run):
    result = confirmed_run["strategic"]
    low, high = result["confirmed"]
    assert result["selections"] == tuple(f"strategic:{name}" for name in result["campaigns"]) and result["confirm"] == 8
    with RunStore(confirmed_run["path"]) as store:
        for label, confirmed, maximize, campaign in (("min", low, False, result["campaigns"][0]), ("max", high, True, result["campaigns"][1])):
            stored = experiments.best(store.evaluations(campaign), maximize)
            assert confirmed.selected.score == stored.score == result[label].score
            assert confirmed.found("return").mean == pytest.approx(stored.score) and confirmed.found("return").n == 2
            assert confirmed.confirmed("return").n == 8 and confirmed.repeats == 8
            assert [s.campaign for s in store.selections(f"strategic:{campaign}")] == [campaign]
        assert searched_keys(store).isdisjoint(fresh_keys([low, high])) and len(fresh_keys([low, high])) == 8 * len({low.digest, high.digest})
        before = rows_of(store)
        again = experiments.strategic_evaluation(store, setup, "return", budget=8, seed=1, progress=False, confirm=8)
        assert rows_of(store) == before  # nothing evaluated or confirmed again
        assert [c.episodes for c in again["confirmed"]] == [low.episodes, high.episodes]
        skipped = experiments.strategic_evaluation(store, setup, "return", budget=8, seed=1, progress=False, confirm=0)
        assert skipped["confirmed"] == (None, None) and rows_of(store) == before


def test_compare_confirms_each_optimiser_and_seed_and_counts_the_confirmation_episodes(setup, confirmed_run):
    runs, confirmed = confirmed_run["runs"], confirmed_run["confirmed"]
    assert {name: len(worlds) for name, worlds in confirmed.items()} == {"cmaes": 2, "random": 2}
    for name, worlds in confirmed.items():
        for seed, (scores, world) in enumerate(zip(runs[name], worlds)):
            assert world.selected.campaign == experiments.comparison_campaign_name(name, False, "return", seed)
            assert world.found("return").mean == pytest.approx(np.nanmin(scores))  # the best within the budget
    everything = [c for worlds in confirmed.values() for c in worlds]
    rows = confirmed_efficiency(runs, confirmed, "return")
    for row in rows:
        assert row["search_episodes"] == 2 * 4 * 2 and row["confirmation_episodes"] == 2 * 8
        assert row["episodes"] == row["search_episodes"] + row["confirmation_episodes"]
        assert row["confirmed_mean"] == pytest.approx(np.mean([c.confirmed("return").mean for c in confirmed[row["optimiser"]]]))
        assert row["confirmed_mean_low"] <= row["confirmed_mean"] <= row["confirmed_mean_high"]
    assert sorted(row["rank"] for row in rows) in ([1, 2], [1, 1])  # ties share a place
    verdict = ordering(rows, confirmed, "return")
    assert verdict["paper"] == ["cmaes", "random"] and verdict["verdict"] in ("survives", "contradicted", "cannot tell")
    assert len(verdict["pairs"]) == 1 and verdict["text"].startswith("On confirmed values (8 fresh episodes per reported world, 2 seeds)")
    with RunStore(confirmed_run["path"]) as store:
        assert searched_keys(store).isdisjoint(fresh_keys(everything))
        assert {s.campaign for s in store.selections("compare:min-return")} == {c.selected.campaign for c in everything}
        before = rows_of(store)
        again = experiments.confirm_optimisers(store, setup, "return", repeats=8, **COMPARE)
        assert {n: [c.episodes for c in w] for n, w in again.items()} == {n: [c.episodes for c in w] for n, w in confirmed.items()}
        assert rows_of(store) == before
        assert experiments.confirm_optimisers(store, setup, "return", repeats=0, **COMPARE) == {}


def test_the_report_reads_the_confirmations_back_and_heads_with_the_confirmed_figure(setup, confirmed_run, tmp_path):
    from worldagent.analysis.confirm import agent_key
    from worldagent.reports.html import comparison_section, strategic_section
    from worldagent.reports.results import headlines, store_results
    from worldagent.runs import RunLayout

    strategic = confirmed_run["strategic"]
    campaigns = experiments.comparison_campaign_names("return", COMPARE["seeds"], COMPARE["optimisers"])
    done = {
        "random": {"status": "done", "outputs": {"campaign": "random-return-s1"}},
        "strategic": {
            "status": "done",
            "outputs": {"campaigns": strategic["campaigns"], "confirmation": {"agent": agent_key(setup), "seed": 1, "repeats": 8}},
        },
        "compare": {
            "status": "done",
            "config": {"budget": 4},
            "outputs": {"campaigns": campaigns, "confirmation": {"agent": agent_key(setup), "seed": 0, "repeats": 8}},
        },
    }
    with RunStore(confirmed_run["path"]) as store:
        res = {"phases": done, "metric": "return", "layout": RunLayout(tmp_path, setup.spec.name), **store_results(setup.spec, store, done)}
    low = strategic["confirmed"][0]
    assert res["min"]["raw"] == strategic["min"].score and res["min"]["confirmed"]["raw"] == low.confirmed("return").as_dict()
    assert res["min"]["confirmed"]["reached"]["episodes"] == 8
    rows = {row.key: row for row in headlines({setup.spec.name: res})}
    assert rows["toy.min.confirmed.raw"].ours == low.confirmed("return").mean and "found " in rows["toy.min.confirmed.raw"].note
    assert rows["toy.min.raw"].ours == strategic["min"].score and "found" in rows["toy.min.raw"].label
    assert [[c.episodes for c in w] for w in res["compare"]["confirmed"].values()] == [
        [c.episodes for c in w] for w in confirmed_run["confirmed"].values()
    ]
    shown = strategic_section(tmp_path, {setup.spec.name: res}) + comparison_section(tmp_path, {setup.spec.name: res})
    assert f'data-key="toy.min.confirmed.raw" data-value="{low.confirmed("return").mean!r}"' in shown
    assert "Ranked by confirmed values" in shown and "data-field='compare-ordering'" in shown
    # a run from before confirmation (no record of one) falls back to the found figures, and says so
    bare = {**done, "strategic": {**done["strategic"], "outputs": {"campaigns": strategic["campaigns"]}}}
    with RunStore(confirmed_run["path"]) as store:
        old = store_results(setup.spec, store, bare)
    assert "confirmed" not in old["min"] and "toy.min.confirmed.raw" not in {row.key for row in headlines({"toy": {**res, **old}})}


def world(values: list[float], found: float = -10.0, seed: int = 0) -> ConfirmedWorld:
    """A confirmed world whose fresh episodes returned ``values`` (and whose found score was ``found``)."""
    picked = Evaluation("c", 0, seed, np.zeros(2), found, [{"return": found}] * 8, 0.0, 0.0)
    return ConfirmedWorld(picked, f"{seed:064x}", [{"return": v} for v in values], seed)


def confirmed_runs(centres: dict[str, list[float]]) -> tuple[dict, dict]:
    """runs and confirmed worlds whose seeds' confirmed means are ``centres`` (± 1 over 8 episodes)."""
    runs = {name: [np.full(5, -10.0) for _ in means] for name, means in centres.items()}
    confirmed = {name: [world([m - 1, m + 1] * 4, seed=i) for i, m in enumerate(means)] for name, means in centres.items()}
    return runs, confirmed


@pytest.mark.parametrize(
    ("centres", "verdict"),
    [
        ({"cmaes": [-50, -49, -51], "bo": [-20, -21, -19], "random": [10, 11, 9]}, "survives"),
        ({"cmaes": [10, 11, 9], "bo": [-20, -21, -19], "random": [30, 31, 29]}, "contradicted"),
        ({"cmaes": [-50, 20, -10], "bo": [-20, 30, -40], "random": [10, 11, 9]}, "cannot tell"),
    ],
)
def test_the_papers_ordering_survives_is_contradicted_or_cannot_be_told(centres, verdict):
    runs, confirmed = confirmed_runs(centres)
    rows = confirmed_efficiency(runs, confirmed, "return")
    found = ordering(rows, confirmed, "return")
    assert found["verdict"] == verdict and found["paper"] == ["cmaes", "bo", "random"]
    assert found["confirmed_order"] == sorted(centres, key=lambda name: np.mean(centres[name]))
    assert {"survives": "survives", "contradicted": "does not survive", "cannot tell": "intervals cannot tell"}[verdict] in found["text"]


def test_a_found_figure_beyond_its_confirmed_interval_the_way_of_the_search_is_called_the_winners_curse():
    lucky = world([-5.0, -3.0] * 32, found=-20.0)
    line = winners_curse(lucky, "return", "min", maximize=False)
    assert "lies below its confirmed interval [-4.2" in line and "winner's curse" in line
    unlucky = winners_curse(lucky, "return", "max", maximize=True)  # a maximum found below its world's value: noise, not the curse
    assert "lies below" in unlucky and "winner's curse" not in unlucky and "unluckier" in unlucky
    assert winners_curse(world([-21.0, -19.0] * 32, found=-20.0), "return", "min", False) == "" and winners_curse(None, "return", "min", False) == ""


def invoke(command: str, toy, generator_dir, out, *arguments: str):
    base = [command, toy.name, "--agent", AGENT, "--generator", str(generator_dir), "--repeats", "2", "--quiet", "--out", str(out)]
    result = runner.invoke(app, [*base, *arguments])
    assert result.exit_code == 0, result.output
    return result.output


@pytest.mark.slow  # ~25 s on 2 loaded cores: three commands, a figure each; the library tests above cover the same in the default run
def test_the_commands_print_found_beside_confirmed_and_zero_skips(toy, generator_dir, tmp_path):
    out = tmp_path / "strategic"
    printed = invoke("strategic", toy, generator_dir, out, "--budget", "4", "--random-worlds", "4", "--confirm", "8")
    assert "min world: found " in printed and "(the selection's, 2 episodes" in printed and "confirmed " in printed and "(8 fresh episodes" in printed
    summary = json.loads((out / "strategic-return-s0.json").read_text())
    assert summary["min"]["found"]["return"]["episodes"] == 2 and summary["min"]["confirmed"]["return"]["episodes"] == 8
    assert summary["min"]["selection"] == "strategic:cmaes-min-return-s0" and summary["confirm"] == 8
    with RunStore(out / "store.sqlite", create=False) as store:
        assert summary["min"]["found_score"] == experiments.best(store.evaluations("cmaes-min-return-s0"), False).score
        confirmations = len(store.confirmations())
    bare = invoke("strategic", toy, generator_dir, tmp_path / "bare", "--budget", "4", "--random-worlds", "4", "--confirm", "0")
    assert "min world: found " in bare and "fresh episodes" not in bare and confirmations >= 1
    with RunStore(tmp_path / "bare" / "store.sqlite", create=False) as store:
        assert store.confirmations() == []

    searched = invoke("search", toy, generator_dir, tmp_path / "search", "--minimize", "--optimiser", "random", "--budget", "4", "--confirm", "8")
    assert "min world" in searched and "confirmed " in searched and "(8 fresh episodes" in searched

    compared = invoke(
        "compare", toy, generator_dir, tmp_path / "compare", "--budget", "4", "--seeds", "2", "--optimisers", "cmaes,random", "--random-worlds", "4"
    )
    table = json.loads((tmp_path / "compare" / "comparison.json").read_text())
    assert [row["confirmation_episodes"] for row in table["confirmed"]] == [2 * 64, 2 * 64]
    assert table["ordering"]["text"] in compared and (tmp_path / "compare" / "comparison-confirmed.csv").is_file()
    assert "| optimiser | rank (confirmed) |" in (tmp_path / "compare" / "comparison.md").read_text()


def test_one_seed_cannot_order_the_optimisers():
    runs, confirmed = confirmed_runs({"cmaes": [10], "bo": [-20], "random": [30]})
    rows = confirmed_efficiency(runs, confirmed, "return")
    found = ordering(rows, confirmed, "return")
    assert any(pair["verdict"] == "reversed" for pair in found["pairs"])  # these two worlds differ beyond doubt...
    assert found["verdict"] == "cannot tell" and "not the optimisers" in found["text"]  # ...which says nothing of the optimisers
