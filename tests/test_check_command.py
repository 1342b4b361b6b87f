"""``worldagent check ENV [--generator DIR]`` (issue 42, item 2): the conformance checks from the installed package,
a table of checks, exit 0 / 1 / 2; descriptors checked on decoded worlds too."""

from __future__ import annotations

import contextlib
import dataclasses

import jax
import numpy as np
import pytest
from typer.testing import CliRunner

import toy_env
from worldagent import conformance
from worldagent.cli import app
from worldagent.conformance import checks, declared
from worldagent.envs import registry
from worldagent.envs.registry import ScriptedPolicy

runner = CliRunner()


@pytest.fixture(scope="module")
def toy():
    with toy_env.registered() as spec:
        yield spec


@contextlib.contextmanager
def variant(name: str, **changes):
    """The toy with ``changes``, registered as ``name`` for the block."""
    spec = registry.register(dataclasses.replace(toy_env.SPEC, name=name, **changes))
    try:
        yield spec
    finally:
        registry.unregister(name)


@pytest.fixture(scope="module")
def wall_free_generator(toy, tmp_path_factory):
    """A toy generator whose repair never builds a wall (threshold 1e9): wall_share is 0 on every decoded world,
    though it varies over generated ones (the stranger's atlas refused such a descriptor)."""
    from worldagent.worlds.dataset import make_dataset
    from worldagent.worlds.generator import build_generator, save_generator
    from worldagent.worlds.vae import VAEConfig, train_vae

    folder = tmp_path_factory.mktemp("toy-generator")
    dataset = make_dataset(toy.name, 64, 0, progress=False)
    dataset.save(folder / "dataset.npz")
    vae = train_vae(dataset, VAEConfig(encoder=(16,), decoder=(16,), epochs=1, batch_size=32, warmup_epochs=0), progress=False)
    return save_generator(folder / "generator", vae, folder / "dataset.npz", build_generator(vae, dataset, {"threshold": 1e9}))


def rows_of(output: str) -> dict[tuple[str, str], str]:
    """{(worlds, check name): status} of the printed table."""
    found = {}
    for check in (*conformance.GENERATED_CHECKS, *conformance.DECODED_CHECKS):
        for line in output.splitlines():
            worlds, _, rest = line.partition(" ")
            if rest.strip().startswith(check.check_name):
                found[(worlds, check.check_name)] = rest.strip()[len(check.check_name) :].split()[0]
    return found


def test_check_passes_a_conforming_env_with_a_table_of_every_check(toy):
    result = runner.invoke(app, ["check", toy.name, "--quiet"])
    assert result.exit_code == 0, result.output
    rows = rows_of(result.output)
    assert {name for worlds, name in rows if worlds == "generated"} == {c.check_name for c in conformance.GENERATED_CHECKS}
    assert set(rows.values()) <= {"pass", "skip"} and "0 failed" in result.output
    assert rows[("generated", declared.world_sets_valid.check_name)] == "skip"  # the toy declares none


def test_check_fails_a_broken_env_naming_each_broken_check(toy):
    constant = {"flat": lambda world: 1.0}  # the atlas refuses a descriptor that never changes
    wild = {"wild": lambda env, params: ScriptedPolicy(None, lambda p, obs, key, state: np.int32(env.num_actions + 3))}
    metrics = dataclasses.replace(toy.metrics, descriptors={**toy.metrics.descriptors, **constant})
    with variant("toy-broken", metrics=metrics, scripted={**toy.scripted, **wild}):
        result = runner.invoke(app, ["check", "toy-broken", "--quiet"])
    assert result.exit_code == 1, result.output
    rows = rows_of(result.output)
    failed = {name for (_, name), status in rows.items() if status == "FAIL"}
    assert failed == {checks.descriptors_vary.check_name, declared.scripted_policies.check_name}
    assert "descriptor 'flat' is 1 on all 64 worlds" in result.output and "wild acts outside 0..3" in result.output
    assert "2 failed" in result.output and "breaks the env contract in 2 check(s)" in result.output


def test_check_with_a_generator_finds_a_descriptor_constant_on_decoded_worlds_only(toy, wall_free_generator):
    result = runner.invoke(app, ["check", toy.name, "--generator", str(wall_free_generator), "--quiet"])
    assert result.exit_code == 1, result.output
    rows = rows_of(result.output)
    name = checks.descriptors_vary.check_name
    assert rows[("generated", name)] == "pass" and rows[("decoded", name)] == "FAIL"
    assert {worlds for worlds, _ in rows} == {"generated", "decoded"}
    assert [key for key, status in rows.items() if status == "FAIL"] == [("decoded", name)]
    assert "descriptor 'wall_share' is 0 on all 512 decoded worlds" in result.output


@pytest.mark.parametrize(
    "arguments, message",
    [
        (["check", "chess"], "unknown environment 'chess'"),
        (["check", "toy", "--generator", "no/such/generator"], "holds no generator; train one with `worldagent generator train toy --out"),
        (["check", "racing", "--generator", "GENERATOR"], "makes toy worlds; pass a racing generator"),
    ],
)
def test_check_refuses_bad_input_with_exit_2(toy, wall_free_generator, arguments, message):
    result = runner.invoke(app, [str(wall_free_generator) if a == "GENERATOR" else a for a in arguments])
    assert result.exit_code == 2 and message in result.output and "Traceback" not in result.output, result.output


def two_grids(valid: bool):
    """Two toy worlds (seeds 5, 6); the second's goal inside a wall unless ``valid``."""
    worlds = jax.tree_util.tree_map(np.array, toy_env.SPEC.generate(np.array([5, 6])))
    if not valid:
        worlds.walls[1] |= worlds.goal[1]
    return worlds


def test_named_world_sets_are_checked_world_by_world(toy):
    with variant("toy-sets", world_sets={"pair": lambda: two_grids(True)}) as spec:
        good = declared.world_sets_valid(conformance.generated_subject(spec))
    assert good.status == conformance.PASS and "pair (2)" in good.reason
    with variant("toy-bad-set", world_sets={"pair": lambda: two_grids(False)}) as spec:
        bad = declared.world_sets_valid(conformance.generated_subject(spec))
    assert bad.status == conformance.FAIL and "world 1 of set 'pair' is refused" in bad.reason and "goal inside a wall" in bad.reason
