"""Conformance of every registered environment to the env contract (issue 11, item 6; issue 42, item 2).

The checks live in the package (``worldagent.conformance``, run by ``worldagent check ENV``); each test here
calls one of them, so each check has one place. Parametrised over ``registry.names()`` at collection, plus the
toy environment of ``tests/toy_env`` (registered for this module only), so an environment registered by a new
folder or an installed plugin is covered without editing this file. Each check is small: a batch of four
worlds, a step limit of ``STEPS``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

import toy_env
from worldagent import conformance
from worldagent.conformance import checks, declared
from worldagent.envs import registry

NAMES = tuple(dict.fromkeys((*registry.names(), toy_env.NAME)))


@pytest.fixture(scope="module", autouse=True)
def _toy_registered():
    with toy_env.registered():
        yield


@pytest.fixture(scope="module", params=NAMES)
def subject(request) -> conformance.Subject:
    """The environment's generated worlds, its functions jitted once for every check of this module."""
    return conformance.generated_subject(registry.get(request.param))


def passes(check, subject) -> conformance.Result:
    """Run ``check``; a failure raises its own exception (with its traceback), a skip is a pytest skip."""
    result = check(subject)
    if result.status == conformance.SKIP:
        pytest.skip(result.reason)
    if not result.passed:
        raise AssertionError(result.reason) from result.error
    assert result.reason and "\n" not in result.reason
    return result


def test_generator_is_deterministic_and_its_worlds_are_accepted(subject):
    passes(checks.generator_deterministic, subject)


def test_reset_and_step_under_jit_and_vmap_over_different_worlds(subject):
    passes(checks.reset_and_step, subject)


def test_same_key_same_episode(subject):
    passes(checks.same_key, subject)


def test_truncated_exactly_at_the_step_limit_unless_terminated(subject):
    passes(checks.truncation, subject)


def test_autoreset_onto_next_world(subject):
    passes(checks.autoreset, subject)


def test_world_store_arrays_round_trip(subject):
    passes(checks.store_round_trip, subject)


def test_malformed_world_is_refused_with_a_one_line_error(subject):
    passes(checks.malformed_refused, subject)


def test_cells_are_binary_with_the_declared_shape(subject):
    passes(checks.cells_binary, subject)


def test_metrics_are_declared(subject):
    passes(declared.metrics_declared, subject)


def test_scripted_policies_act_with_the_right_action_shape(subject):
    passes(declared.scripted_policies, subject)


def test_repair_makes_dataset_cells_valid_worlds(subject):
    passes(declared.repair_valid, subject)


def test_declared_algorithms_pictures_and_presets(subject):
    passes(declared.declared_usable, subject)


def test_an_unknown_default_optimiser_fails_the_declared_check(subject, monkeypatch):
    monkeypatch.setattr(subject, "spec", dataclasses.replace(subject.spec, optimiser="annealing"))
    result = declared.declared_usable(subject)
    assert not result.passed and "optimiser 'annealing': use one of cmaes, bo, random" in result.reason


def test_actor_critic_algorithms_get_a_flat_observation(subject):
    passes(declared.flat_observation, subject)


def test_descriptors_vary_over_generated_worlds(subject):
    """``worldagent atlas`` refuses a descriptor constant over its 512 G(z) samples; one constant over the
    procedural generator's worlds would be."""
    passes(checks.descriptors_vary, subject)


def test_episode_pictures_draw_episodes(subject):
    passes(checks.episode_pictures, subject)


def test_failure_and_training_check_are_usable(subject):
    passes(declared.failure_usable, subject)


def test_named_world_sets_are_valid_worlds(subject):
    passes(declared.world_sets_valid, subject)


def test_every_generated_check_of_the_package_runs_here():
    """A check added to the package without a test here would run in `worldagent check` only."""
    source = Path(__file__).read_text()
    assert [check.__name__ for check in conformance.GENERATED_CHECKS if f".{check.__name__}, subject)" not in source] == []
