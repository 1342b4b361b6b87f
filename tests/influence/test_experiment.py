"""The influencing experiment on tiny budgets: reproducible, cached, resumable; Figure 8."""

from __future__ import annotations

import dataclasses
import json
import math

import jax
import numpy as np
import pytest
from PIL import Image

from worldagent.agents.dqn import DQNConfig
from worldagent.agents.policy import Policy
from worldagent.agents.ppo import PPOConfig
from worldagent.agents.training import CURVE_FILE, read_curve
from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.experiments import example_worlds, influence, setup
from worldagent.influence import load_influenced_worlds
from worldagent.influence.experiment import training_failures
from worldagent.influence.statistics import mean_and_ci
from worldagent.influence.worlds import example_indices
from worldagent.reports.influence import influence_figure
from worldagent.store import RunStore

pytestmark = pytest.mark.integration  # whole-pipeline work: .ci/run's integration step runs it

TINY_PPO = PPOConfig(total_episodes=8, num_envs=4, num_steps=16, num_minibatches=2, update_epochs=1, hidden=(8,))
SELECT = "crash_rate > 0.5 and progress > 0.005"  # a random driver crashes; some worlds let it get further
TINY_DQN = DQNConfig(
    num_episodes=8,
    num_envs=8,
    hidden_sizes=(16,),
    batch_size=32,
    buffer_size=1000,
    learning_starts=50,
    target_update_every=20,
    epsilon_decay_episodes=4,
)


def random_driver() -> Policy:
    return Policy(None, lambda params, obs, key, state=None: jax.random.randint(key, (), 0, 4), "random")


def racing_setup(generator):
    """Random driving, 2 episodes per world, evaluated over 60-step episodes (fast)."""
    base = setup("racing", random_driver(), generator, repeats=2)
    return dataclasses.replace(base, params=base.params.replace(max_steps=60))


def run_racing(run_dir, generator, selection=SELECT):
    return influence(
        run_dir,
        racing_setup(generator),
        selection,
        algo="ppo",
        episodes=8,
        seeds=(0, 1),
        candidates=24,
        eval_worlds=8,
        config=TINY_PPO,
        progress=False,
    )


def file_times(directory) -> dict:
    return {str(p.relative_to(directory)): p.stat().st_mtime_ns for p in sorted(directory.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def racing_run(tmp_path_factory, racing_generator):
    run_dir = tmp_path_factory.mktemp("influence") / "a"
    return run_dir, run_racing(run_dir, racing_generator)


def test_the_result_has_counts_per_seed_numbers_and_a_summary(racing_run):
    run_dir, result = racing_run
    assert result["worlds"]["tried"] == 24 and 1 <= result["worlds"]["selected"] < 24
    assert result["metrics"] == ["return", "normalised_return", "crashed", "lap_completed"]
    assert set(result["per_seed"]) == {"default", "influenced"} and set(result["per_seed"]["default"]) == {"0", "1"}
    for metric in result["metrics"]:
        for label in ("default", "influenced"):
            values = [result["per_seed"][label][s][metric] for s in ("0", "1")]
            entry = result["summary"][metric][label]
            assert entry["mean"] == pytest.approx(np.mean(values)) and entry["seeds"] == 2
            assert entry["ci95"] == pytest.approx(12.7062047 * np.std(values, ddof=1) / math.sqrt(2))  # t(0.975, 1)
    assert 0 <= result["summary"]["normalised_return"]["default"]["mean"] <= 1
    assert set(result["wall_seconds"]) >= {"candidates", "train", "evaluate", "total"}
    on_disk = json.loads((run_dir / "influence.json").read_text())
    assert on_disk["summary"] == result["summary"] and on_disk["selection"]["text"] == SELECT
    for name in ("default-s0", "influenced-s0", "default-s1", "influenced-s1"):
        assert (run_dir / "agents" / name / "policy" / "policy.json").is_file()
    worlds, latents, values = load_influenced_worlds(run_dir, "racing")
    assert len(latents) == result["worlds"]["selected"] == worlds.centreline.shape[0]
    assert np.all(values["crashed"] > 0.5) and np.all(values["progress"] > 0.005)
    with RunStore(run_dir, create=False) as store:
        evaluations = store.evaluations()
        names = [c.name for c in store.campaigns()]
    assert names[0] == "influence-candidates" and len(names) == 5
    eval_latents = {c: [e.latent.tolist() for e in evaluations if e.campaign == c] for c in names[1:]}
    assert len({json.dumps(v) for v in eval_latents.values()}) == 1  # every agent on the same 8 worlds


def test_a_second_run_into_another_directory_gives_identical_numbers(racing_run, tmp_path, racing_generator):
    _, first = racing_run
    second = run_racing(tmp_path / "b", racing_generator)
    assert second["per_seed"] == first["per_seed"]
    assert second["summary"] == first["summary"]
    assert second["worlds"] == first["worlds"]


def test_a_rerun_trains_and_evaluates_nothing_new(racing_run, racing_generator):
    run_dir, first = racing_run
    before = file_times(run_dir / "agents")
    with RunStore(run_dir, create=False) as store:
        evaluations = len(store.evaluations())
    again = run_racing(run_dir, racing_generator)
    assert file_times(run_dir / "agents") == before
    assert again["per_seed"] == first["per_seed"] and again["summary"] == first["summary"]
    assert again["wall_seconds"]["total"] < 5
    with RunStore(run_dir, create=False) as store:
        assert len(store.evaluations()) == evaluations


def test_an_unfinished_agent_is_resumed_from_its_checkpoint(racing_run, racing_generator):
    run_dir, first = racing_run
    (run_dir / "agents" / "influenced-s1" / "trained.json").unlink()  # as if killed after its last checkpoint
    untouched = file_times(run_dir / "agents" / "default-s0")
    again = run_racing(run_dir, racing_generator)
    resumed = run_dir / "agents" / "influenced-s1"
    assert (resumed / "trained.json").is_file()
    # its recorded training time is the whole training's (the curve's clock), not the resume's
    assert json.loads((resumed / "trained.json").read_text())["wall_seconds"] == read_curve(resumed / CURVE_FILE)[-1]["wall_seconds"]
    assert file_times(run_dir / "agents" / "default-s0") == untouched
    assert again["per_seed"] == first["per_seed"]


def test_a_run_dir_made_with_other_settings_is_refused(racing_run, racing_generator):
    run_dir, _ = racing_run
    with pytest.raises(WorldagentError, match=r"other settings \(selection\).*--out"):
        run_racing(run_dir, racing_generator, "crash_rate > 0.9")


def test_a_selection_that_matched_nothing_can_be_loosened_in_the_same_directory(racing_run, tmp_path, racing_generator):
    run_dir, _ = racing_run
    with pytest.raises(WorldagentError, match="none of the 24 worlds tried matches 'progress > 5'"):
        run_racing(tmp_path, racing_generator, "progress > 5")
    plan = json.loads((tmp_path / "plan.json").read_text())
    assert set(plan) == {"worlds"}  # the training stage is recorded only once a selection matched
    assert plan["worlds"] == json.loads((run_dir / "plan.json").read_text())["worlds"]
    assert not (tmp_path / "agents").exists()


def test_bad_arguments_are_refused_before_any_work(tmp_path, racing_generator, harvest_generator):
    racing = racing_setup(racing_generator)
    with pytest.raises(WorldagentError, match="unknown algorithm 'dqn' for racing"):
        influence(tmp_path, racing, SELECT, algo="dqn", episodes=8)
    with pytest.raises(WorldagentError, match="makes harvest worlds"):
        influence(tmp_path, dataclasses.replace(racing, generator=harvest_generator), SELECT, episodes=8)
    with pytest.raises(WorldagentError, match="seeds"):
        influence(tmp_path, racing, SELECT, episodes=8, seeds=())
    with pytest.raises(WorldagentError, match="episodes=0"):
        influence(tmp_path, racing, SELECT, episodes=0)
    with pytest.raises(WorldagentError, match="unknown racing metric 'conflict'"):
        influence(tmp_path, racing, "conflict == 0", algo="ppo", episodes=8)
    assert not (tmp_path / "store.sqlite").exists()


def test_one_seed_has_no_interval_rather_than_a_zero_one():
    assert math.isnan(mean_and_ci([0.3])["ci95"]) and mean_and_ci([0.3])["mean"] == 0.3
    assert mean_and_ci([1.0, 1.0, 1.0])["ci95"] == 0.0
    assert mean_and_ci([0.0, 1.0, 2.0])["ci95"] == pytest.approx(4.30265273 / math.sqrt(3))  # t(0.975, 2) * sd / sqrt(3)


def test_harvest_with_a_search_for_more_worlds_and_figure_8(tmp_path, harvest_generator):
    harvest = setup("harvest", "random", harvest_generator, options={"tagger": (0,)}, repeats=2)
    harvest = dataclasses.replace(harvest, params=harvest.params.replace(max_steps=40))  # short evaluation episodes
    result = influence(
        tmp_path, harvest, "conflict == 0", episodes=8, seeds=(0,), candidates=16, search_budget=12, eval_worlds=8, config=TINY_DQN, progress=False
    )
    assert result["algo"] == "dqn"  # the env's default algorithm
    assert result["worlds"]["campaigns"] == ["influence-candidates", "influence-search"]
    assert result["worlds"]["tried"] == 16 + 21  # CMA-ES evaluates whole generations of 21
    assert result["metrics"] == ["group_reward", "conflict", "equality"]
    assert result["config"]["options"] == {"tagger": [0], "view_size": 15, "view_behind": 2, "beam_length": 5, "regrowth": 1.0}  # defaults filled in
    assert math.isnan(result["summary"]["equality"]["default"]["ci95"])
    assert json.loads((tmp_path / "influence.json").read_text())["summary"]["equality"]["default"]["ci95"] is None
    assert (tmp_path / "agents" / "default-s0" / "policy").is_dir()
    worlds, _, values = load_influenced_worlds(tmp_path, "harvest")
    assert np.all(values["conflict"] == 0)
    picks = example_indices(values, 4)
    assert 1 <= len(picks) <= 4 and len(set(picks.tolist())) == len(picks)
    examples = example_worlds(tmp_path, "harvest", 4)
    np.testing.assert_array_equal(examples.walls, np.asarray(worlds.walls)[picks])
    figure = influence_figure(json.loads((tmp_path / "influence.json").read_text()), examples, "harvest", tmp_path / "figure.png")
    with Image.open(figure) as image:
        assert image.size[0] > image.size[1] > 100


def test_agents_that_failed_to_learn_are_warned_of_and_recorded(racing_run, racing_generator):
    run_dir, result = racing_run  # agents of 8 training episodes never lap
    assert set(result["failed_training"]) == {"default-s0", "default-s1", "influenced-s0", "influenced-s1"}
    assert "laps in only 0% of its episodes" in result["failed_training"]["influenced-s1"]
    with pytest.warns(UserWarning, match="the influenced-s1 agent laps in only 0%"):
        run_racing(run_dir, racing_generator)  # a rerun (nothing new trained) says it again
    assert training_failures(registry.get("racing"), {"default": {"0": {"lap_completed": 0.93}}}) == {}
    assert training_failures(registry.get("harvest"), {"default": {"0": {"conflict": 0.0}}}) == {}  # harvest has no check


@pytest.mark.slow  # ~14 s; the atlas is tested by default in tests/search, the influence search by the harvest test above
def test_an_atlas_search_collects_distinct_worlds_with_the_property(tmp_path, racing_generator):
    result = influence(
        tmp_path,
        racing_setup(racing_generator),
        SELECT,
        algo="ppo",
        episodes=8,
        seeds=(0,),
        candidates=24,
        search_budget=105,  # the 10 x 10 grid needs at least 100
        search="atlas",
        eval_worlds=4,
        config=TINY_PPO,
        progress=False,
    )
    assert result["worlds"]["tried"] == 24 + 105 and result["config"]["search"] == "atlas"
    with RunStore(tmp_path, create=False) as store:
        campaign = store.campaign("influence-search")
        assert campaign.optimiser == "cma-me" and campaign.config["atlas"]["grid"]["descriptors"] == ["total_curvature", "sharpest_corner"]
    worlds, _, _ = load_influenced_worlds(tmp_path, "racing")
    assert len(np.unique(np.asarray(worlds.road).reshape(len(worlds.road), -1), axis=0)) == result["worlds"]["selected"]  # distinct
    with pytest.raises(WorldagentError, match="unknown search 'grid'; use one of: cmaes, atlas"):
        influence(tmp_path / "b", racing_setup(racing_generator), SELECT, episodes=8, search="grid")


def test_racing_figure_from_the_returned_result(racing_run, tmp_path):
    run_dir, result = racing_run
    worlds, _, values = load_influenced_worlds(run_dir, "racing")
    examples = jax.tree_util.tree_map(lambda leaf: leaf[example_indices(values, 2)], worlds)
    with Image.open(influence_figure(result, examples, "racing", tmp_path / "f.png")) as image:
        assert image.size[0] > 300
    with pytest.raises(WorldagentError, match="no summary"):
        influence_figure({}, None, "racing", tmp_path / "g.png")
