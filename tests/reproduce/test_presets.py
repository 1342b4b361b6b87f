"""Presets: built from the specs, printable, validated, and sliced per phase (what a resumed run compares)."""

from __future__ import annotations

import json

import pytest

from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.reproduce.phases import dependents
from worldagent.reproduce.pipeline import resolve_envs, restart_closure
from worldagent.reproduce.presets import PHASES, SETTINGS, EnvBudgets, get_preset

PAPER, QUICK, TINY = (get_preset(name) for name in ("paper", "quick", "tiny"))


def test_paper_preset_has_the_papers_budgets():
    racing, harvest = PAPER.budgets("racing"), PAPER.budgets("harvest")
    assert racing.worlds == harvest.worlds == 10_000
    assert (racing.episodes, harvest.episodes) == (10_000, 5_000)
    assert PAPER.repeats == 8 and racing.random_worlds == harvest.random_worlds == 1_000
    assert PAPER.vae_hidden == (1024, 512)
    assert (PAPER.algo_of("racing"), PAPER.algo_of("harvest")) == ("acktr", "dqn")  # the paper's algorithms
    assert PAPER.options_of("racing") == {"observation": "rays"} and QUICK.options_of("racing") == {}  # the paper's racing observation


def test_budgets_come_from_the_specs():
    for name in SETTINGS:
        preset = get_preset(name)
        assert list(preset.envs) == [env for env in registry.names() if name in registry.get(env).presets]
        for env, budgets in preset.envs.items():
            assert budgets == EnvBudgets(**registry.get(env).presets[name])


def test_options_and_selections_come_from_the_specs():
    assert TINY.phase_config("harvest", "agent")["options"] == {"tagger": (0,)}  # harvest's reproduce_options
    assert PAPER.phase_config("racing", "agent")["options"] == {"observation": "rays"}  # the racing budgets' options
    assert "options" not in TINY.phase_config("racing", "agent") and "options" not in QUICK.phase_config("racing", "agent")
    assert TINY.selection("harvest") == registry.get("harvest").selection == "conflict == 0"
    assert QUICK.selection("racing") == "crash_rate > 0"  # the racing budgets override the paper's selection
    assert TINY.selection("racing") == registry.get("racing").selection != PAPER.selection("racing")


@pytest.mark.parametrize("name", list(SETTINGS))
def test_presets_print_as_json_and_slice_every_phase(name):
    preset = get_preset(name)
    shown = json.loads(preset.show())
    assert shown["name"] == name and shown["envs"]["racing"]["worlds"] == preset.budgets("racing").worlds
    for env in preset.envs:
        for phase in PHASES:
            assert preset.phase_config(env, phase)["seed"] == preset.seed


def test_a_budget_change_touches_only_its_phase():
    changed = QUICK.with_budgets("racing", random_worlds=7)
    differ = [p for p in PHASES if changed.phase_config("racing", p) != QUICK.phase_config("racing", p)]
    assert differ == ["random"]
    assert changed.phase_config("harvest", "random") == QUICK.phase_config("harvest", "random")


def test_a_presets_own_training_settings_reach_its_agents_and_set_wins_over_them():
    """Harvest's quick DQN halves the minibatch (the budgets' settings); ``--set`` overrides it, for that algorithm only."""
    assert QUICK.settings_of("harvest")["batch_size"] == 64 and QUICK.phase_config("harvest", "influence")["settings"]["batch_size"] == 64
    assert "settings" not in PAPER.phase_config("harvest", "agent")
    changed = QUICK.with_settings({"dqn": {"batch_size": 32}, "ppo": {"learning_rate": 1e-3}})
    assert changed.settings_of("harvest")["batch_size"] == 32 and changed.settings_of("harvest")["epsilon_decay_fraction"] == 1.0
    assert changed.settings_of("racing") == {"learning_rate": 1e-3}


def test_the_strategic_phase_searches_with_the_envs_optimiser_and_the_paper_preset_with_cmaes():
    """Harvest's searches default to BO (it found lower worlds on fresh episodes); its paper preset keeps the paper's CMA-ES."""
    assert registry.get("harvest").optimiser == "bo" and registry.get("racing").optimiser == "cmaes"
    assert QUICK.phase_config("harvest", "strategic")["optimiser"] == "bo"
    assert QUICK.phase_config("racing", "strategic")["optimiser"] == "cmaes"
    assert PAPER.phase_config("harvest", "strategic")["optimiser"] == "cmaes"


def test_algo_overrides_only_the_envs_that_have_it():
    acktr, ppo = TINY.with_algo("acktr"), PAPER.with_algo("ppo")
    assert (TINY.algo_of("racing"), acktr.algo_of("racing"), acktr.algo_of("harvest")) == ("ppo", "acktr", "dqn")
    assert acktr.phase_config("racing", "agent")["algo"] == "acktr" and acktr.phase_config("harvest", "agent") == TINY.phase_config(
        "harvest", "agent"
    )
    assert (PAPER.algo_of("racing"), ppo.algo_of("racing")) == ("acktr", "ppo")  # --algo overrides the preset's own


def test_bad_names_and_budgets_are_refused_in_one_line():
    with pytest.raises(WorldagentError, match="unknown preset 'huge'; use one of: tiny, quick, paper"):
        get_preset("huge")
    with pytest.raises(WorldagentError, match="algorithm 'sarsa' trains none of racing, harvest"):
        TINY.with_algo("sarsa")
    with pytest.raises(WorldagentError, match="episodes"):
        TINY.with_budgets("racing", episodes=0)
    with pytest.raises(WorldagentError, match="racing trains with ppo, acktr, not 'dqn'"):
        TINY.with_budgets("racing", algo="dqn")
    with pytest.raises(WorldagentError, match="racing has no option 'colour'"):
        TINY.with_budgets("racing", options={"colour": 1})
    with pytest.raises(WorldagentError, match="influence_search 'bo'; use one of: cmaes, atlas"):
        TINY.with_budgets("racing", influence_search="bo")
    with pytest.raises(WorldagentError, match="unknown environment 'chess'"):
        resolve_envs("chess", TINY)
    assert resolve_envs("all", TINY) == list(TINY.envs) and resolve_envs("harvest", TINY) == ["harvest"]  # all: with installed plugins
    assert list(TINY.envs)[:2] == ["racing", "harvest"]
    assert resolve_envs("harvest, racing,harvest", TINY) == ["harvest", "racing"]  # several, in the order named, once each
    with pytest.raises(WorldagentError, match="unknown environment 'chess'"):
        resolve_envs("racing,chess", TINY)


def test_restarting_a_phase_restarts_what_is_computed_from_it():
    assert dependents("influence") == ["influence"]
    assert dependents("random") == ["random", "strategic", "compare"]
    assert dependents("agent") == ["agent", "random", "strategic", "compare", "influence", "atlas"]
    assert dependents("atlas") == ["atlas"]
    assert restart_closure(["dataset"]) == list(PHASES)
    assert restart_closure(["compare", "strategic"]) == ["strategic", "compare"]
    with pytest.raises(WorldagentError, match="unknown phase 'train'"):
        restart_closure(["train"])


def test_a_named_repair_is_part_of_the_generator_phases_config_and_checked_per_env():
    assert "repair" not in TINY.phase_config("racing", "generator")  # runs made before --repair still match
    opened = TINY.with_repair("open")
    assert opened.phase_config("racing", "generator")["repair"] == "open"
    assert [p for p in PHASES if opened.phase_config("racing", p) != TINY.phase_config("racing", p)] == ["generator"]
    opened.check_repair("racing")
    with pytest.raises(WorldagentError, match="has no repair 'closest'"):
        TINY.with_repair("closest").check_repair("racing")
