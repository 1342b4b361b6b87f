"""Influence selects from confirmed worlds (issue 50 item 6): only the selected worlds that keep the property on
fresh episodes are trained on; ``confirm=0`` is the raw selection; a rerun replays nothing."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

import toy_env
from worldagent.agents.ppo import PPOConfig
from worldagent.analysis.confirm import ConfirmedWorld, mean_interval, metric_values
from worldagent.cli import app
from worldagent.errors import WorldagentError
from worldagent.events import parse_selection
from worldagent.experiments import influence, setup
from worldagent.influence.cache import load_influenced_worlds
from worldagent.influence.confirmation import confirmation_line, confirmation_summary, confirmed_property, none_survived
from worldagent.influence.worlds import select_worlds
from worldagent.reports.influence import confirmation_sentence, training_worlds
from worldagent.store import Evaluation, RunStore, world_digest

TINY = PPOConfig(total_episodes=8, num_envs=4, num_steps=8, num_minibatches=2, update_epochs=1, hidden=(8,))
SELECT = "reached < 0.5"  # a random walker misses the goal of some grids in most episodes, of others not
CONFIRM = 8


@pytest.fixture(scope="module")
def toy():
    with toy_env.registered() as spec:
        yield spec


@pytest.fixture(scope="module")
def toy_generator(toy):
    from worldagent.worlds.dataset import make_dataset
    from worldagent.worlds.generator import build_generator
    from worldagent.worlds.vae import VAEConfig, train_vae

    dataset = make_dataset(toy.name, 64, 0, progress=False)
    vae = train_vae(dataset, VAEConfig(encoder=(32,), decoder=(32,), epochs=1, batch_size=32, warmup_epochs=1), progress=False)
    return build_generator(vae, dataset)


def run(run_dir, toy, generator, confirm):
    return influence(
        run_dir,
        setup(toy.name, "random", generator, repeats=2),
        SELECT,
        episodes=8,
        seeds=(0,),
        candidates=16,
        eval_worlds=2,
        config=TINY,
        progress=False,
        confirm=confirm,
    )


@pytest.fixture(scope="module")
def selections(tmp_path_factory, toy, toy_generator):
    """Steps (a) and the selection alone (no training), raw and confirmed, in one store: {confirm: find_worlds' result}."""
    from worldagent.influence.experiment import find_worlds
    from worldagent.influence.worlds import resolved

    chosen = setup(toy.name, "random", toy_generator, repeats=2)
    counts = {"candidates": 16, "search_budget": 0, "repeats": 2, "seed": 0, "options": {}}
    selection = resolved(SELECT, toy)
    with RunStore(tmp_path_factory.mktemp("selection")) as store:
        found = {
            c: find_worlds(store, toy, chosen.env, chosen.params, chosen.policy, toy_generator, selection, {**counts, "confirm": c}, False)
            for c in (0, CONFIRM)
        }
        return store.path.parent, found


def test_find_worlds_keeps_exactly_the_selected_worlds_confirmed_to_miss_the_goal(selections, toy):
    where, found = selections
    with RunStore(where, create=False) as store:
        raw, _, raw_values = select_worlds(store, ["influence-candidates"], SELECT, toy.name)
        fresh = {c.world: c.episodes for c in store.confirmations(env=toy.name)}
        assert [s.world for s in store.selections(f"influence:{SELECT}")] == digests(raw, toy)
    raw_digests = digests(raw, toy)
    unconfirmed, confirmed = found[0], found[CONFIRM]
    assert digests(unconfirmed[2], toy) == raw_digests and unconfirmed[5] is None  # confirm 0: the raw selection, as before
    assert unconfirmed[4]["reached"].tolist() == raw_values["reached"].tolist()
    expected = [d for d in raw_digests if mean_interval(metric_values(fresh[d], "reached")).high < 0.5]
    assert digests(confirmed[2], toy) == expected and 0 < len(expected) < len(raw_digests)
    summary = confirmed[5]
    assert (summary["selected"], summary["survived"]) == (len(raw_digests), len(expected))
    assert summary["property"]["kept_confirmed"]["mean"] == pytest.approx(1 - np.mean([metric_values(fresh[d], "reached").mean() for d in expected]))


def test_find_worlds_again_confirms_nothing_new(selections, toy, toy_generator, monkeypatch):
    from worldagent.influence.experiment import find_worlds
    from worldagent.influence.worlds import resolved

    where, found = selections

    def replayed(*args, **kwargs):
        raise AssertionError("a finished confirmation was replayed")

    monkeypatch.setattr("worldagent.search.given.GivenWorlds", replayed)
    chosen = setup(toy.name, "random", toy_generator, repeats=2)
    counts = {"candidates": 16, "search_budget": 0, "repeats": 2, "seed": 0, "options": {}, "confirm": CONFIRM}
    with RunStore(where, create=False) as store:
        before = len(store.confirmations())
        again = find_worlds(store, toy, chosen.env, chosen.params, chosen.policy, toy_generator, resolved(SELECT, toy), counts, False)
        assert len(store.confirmations()) == before
    assert digests(again[2], toy) == digests(found[CONFIRM][2], toy) and again[5] == found[CONFIRM][5]


@pytest.fixture(scope="module")
def runs(tmp_path_factory, toy, toy_generator):
    """The same candidates selected raw (confirm 0) and confirmed on 8 fresh episodes: {confirm: (run dir, result)}."""
    root = tmp_path_factory.mktemp("confirmed")
    return {confirm: (root / f"c{confirm}", run(root / f"c{confirm}", toy, toy_generator, confirm)) for confirm in (0, CONFIRM)}


def digests(worlds, spec) -> list[str]:
    arrays = spec.world_to_arrays(worlds)
    return [world_digest({k: np.asarray(v[i]) for k, v in arrays.items()}) for i in range(len(next(iter(arrays.values()))))]


@pytest.mark.slow  # ~50 s of CPU: two influence runs (each trains two agents); the selection alone is tested above
def test_the_survivors_are_exactly_the_selected_worlds_confirmed_to_miss_the_goal(runs, toy):
    run_dir, result = runs[CONFIRM]
    with RunStore(run_dir, create=False) as store:
        raw, _, _ = select_worlds(store, ["influence-candidates"], SELECT, toy.name)
        fresh = {c.world: c.episodes for c in store.confirmations(env=toy.name) if c.seed == 0}  # the run's seed: the selection's
        picked = [s.world for s in store.selections(f"influence:{SELECT}")]
    raw_digests = digests(raw, toy)
    assert picked == raw_digests and set(fresh) == set(raw_digests)  # every raw pick replayed once, with provenance
    assert all(len(episodes) == CONFIRM for episodes in fresh.values())
    # reached < 0.5 confirmed: the exact binomial interval of the fresh episodes' reach rate wholly below 0.5
    expected = [d for d in raw_digests if mean_interval(metric_values(fresh[d], "reached")).high < 0.5]
    worlds, _, values = load_influenced_worlds(run_dir, toy.name)
    assert digests(worlds, toy) == expected
    assert 0 < len(expected) < len(raw_digests)  # the run must both keep and drop worlds for this to mean anything
    assert np.all(values["reached"] < 0.5)  # the values kept are as found
    counts = result["worlds"]
    assert counts["selected"] == len(expected) and counts["raw_selected"] == len(raw_digests)
    confirmation = counts["confirmation"]
    assert (confirmation["selected"], confirmation["survived"], confirmation["repeats"]) == (len(raw_digests), len(expected), CONFIRM)
    kept_rate = np.mean([metric_values(fresh[d], "reached").mean() for d in expected])
    assert confirmation["property"]["event"] == "reached < 0.5"
    assert confirmation["property"]["kept_confirmed"]["mean"] == pytest.approx(1 - kept_rate)  # the share of fresh episodes missing
    assert confirmation["property"]["selected_found"]["mean"] > confirmation["property"]["selected_confirmed"]["mean"]  # the winner's curse
    assert result["config"]["confirm"] == CONFIRM
    assert json.loads((run_dir / "plan.json").read_text())["training"]["confirm"] == CONFIRM
    assert json.loads((run_dir / "influence.json").read_text())["worlds"]["confirmation"]["survived"] == len(expected)
    line = confirmation_line(confirmation)
    assert f"{len(expected)} of {len(raw_digests)} selected worlds keep reached < 0.5" in line and "found" in line
    assert training_worlds(result) == f"reached < 0.5, {len(expected)} of {len(raw_digests)} confirmed on {CONFIRM} fresh episodes"
    assert f"{len(expected)} kept it on {CONFIRM} fresh episodes" in confirmation_sentence(result)


@pytest.mark.slow  # shares the two influence runs above
def test_confirm_0_trains_on_the_raw_selection_as_before(runs, toy):
    run_dir, result = runs[0]
    confirmed_dir, _ = runs[CONFIRM]
    with RunStore(run_dir, create=False) as store:
        raw, _, raw_values = select_worlds(store, ["influence-candidates"], SELECT, toy.name)
        assert store.confirmations() == [] and store.selections() == []
    worlds, _, values = load_influenced_worlds(run_dir, toy.name)
    assert digests(worlds, toy) == digests(raw, toy) and values["reached"].tolist() == raw_values["reached"].tolist()
    assert "confirmation" not in result["worlds"] and "raw_selected" not in result["worlds"] and "confirm" not in result["config"]
    assert "confirm" not in json.loads((run_dir / "plan.json").read_text())["training"]  # plans made before the option still match
    with RunStore(confirmed_dir, create=False) as store:
        assert len(store.selections()) == result["worlds"]["selected"]  # the confirmed run started from the same raw selection
    assert training_worlds(result) == "reached < 0.5" and confirmation_sentence(result) == ""


@pytest.mark.slow  # shares the two influence runs above
def test_a_rerun_confirms_nothing_new_and_another_confirm_is_refused(runs, toy, toy_generator, monkeypatch):
    run_dir, first = runs[CONFIRM]
    with RunStore(run_dir, create=False) as store:
        before = [(c.world, c.episodes) for c in store.confirmations()]

    def replayed(*args, **kwargs):
        raise AssertionError("a finished confirmation was replayed")

    monkeypatch.setattr("worldagent.search.given.GivenWorlds", replayed)
    again = run(run_dir, toy, toy_generator, CONFIRM)
    assert again["worlds"] == first["worlds"] and again["per_seed"] == first["per_seed"]
    with RunStore(run_dir, create=False) as store:
        assert [(c.world, c.episodes) for c in store.confirmations()] == before
    with pytest.raises(WorldagentError, match=r"other settings \(confirm\).*--out"):
        run(run_dir, toy, toy_generator, 16)
    with pytest.raises(WorldagentError, match=r"other settings \(confirm\)"):
        run(run_dir, toy, toy_generator, 0)


def fake(digest: str, found: list[float], fresh: list[float]) -> ConfirmedWorld:
    evaluation = Evaluation("c", 0, 0, np.zeros(1), 0.0, [{"conflict": v} for v in found], 0.0, 0.0)
    return ConfirmedWorld(evaluation, digest, [{"conflict": v} for v in fresh], 0)


def test_an_equality_is_confirmed_only_on_every_fresh_episode_and_none_surviving_says_what_to_do():
    selection = parse_selection("conflict == 0", "harvest").resolve("harvest")
    clean, once = fake("a", [0.0] * 8, [0.0] * 32), fake("b", [0.0] * 8, [0.0] * 31 + [0.02])
    assert confirmed_property(clean, selection) and not confirmed_property(once, selection)
    summary = confirmation_summary([clean, once], [clean], selection, None, 32, 0)
    assert (summary["selected"], summary["survived"], summary["survived_share"]) == (2, 1, 0.5)
    assert summary["property"]["selected_found"]["mean"] == 1.0 and summary["property"]["kept_confirmed"]["mean"] == 1.0
    assert summary["property"]["selected_confirmed"]["mean"] == pytest.approx((1 + 31 / 32) / 2)
    error = none_survived(confirmation_summary([once], [], selection, None, 32, 0), selection)
    assert "none of the 1 worlds with 'conflict == 0' kept it on 32 fresh episodes" in str(error) and "--confirm 0" in str(error)


def test_a_negative_confirm_exits_2_with_one_line(tmp_path, toy):
    from worldagent.influence.experiment import influence as run_influence

    common = ["--agent", "driver", "--generator", str(tmp_path), "--out", str(tmp_path / "run"), "--select", "reward > 0"]
    result = CliRunner().invoke(app, ["influence", "racing", *common, "--confirm", "-1"])
    assert result.exit_code == 2 and "--confirm is -1" in result.output and len(result.output.strip().splitlines()) == 1
    with pytest.raises(WorldagentError, match=r"confirm=-1; .*--confirm"):
        run_influence(tmp_path, toy, None, None, None, None, SELECT, episodes=8, confirm=-1)  # before anything loads
    assert not (tmp_path / "store.sqlite").exists()


@pytest.mark.slow  # shares the two influence runs above
def test_every_trained_agent_replays_the_kept_worlds_under_its_own_identity(runs, toy, toy_generator):
    from worldagent.influence.confirmation import REPLAY_SEED_OFFSET, trained_on_selected

    run_dir, result = runs[CONFIRM]
    chosen = setup(toy.name, "random", toy_generator, repeats=2)
    events = {"selection": parse_selection(SELECT, toy.name).resolve(toy.name)}
    replayed = trained_on_selected(run_dir, chosen, result, events, repeats=3, progress=False)
    kept = result["worlds"]["selected"]
    assert (replayed["worlds"], replayed["repeats"], replayed["seed"]) == (kept, 3, REPLAY_SEED_OFFSET)
    with RunStore(run_dir, create=False) as store:
        rows = [c for c in store.confirmations(env=toy.name) if c.seed == REPLAY_SEED_OFFSET]
    assert len(rows) == 2 * kept and len({c.agent for c in rows}) == 2  # default-s0 and influenced-s0, each its own rows
    by_agent: dict[str, list[float]] = {}
    for c in rows:
        by_agent.setdefault(c.agent, []).append(1 - metric_values(c.episodes, "reached").mean())  # the share missing the goal
    measured = sorted(float(np.mean(v)) for v in by_agent.values())
    reported = sorted(replayed["per_seed"][label]["0"]["selection"] for label in ("default", "influenced"))
    assert reported == pytest.approx(measured)
    assert set(replayed["per_seed"]["default"]["0"]) == {"selection", "return", "reached"}
    pooled = replayed["pooled"]["selection"]
    assert pooled["difference"] == pytest.approx(pooled["arm"] - pooled["base"]) and pooled["worlds"] == kept
