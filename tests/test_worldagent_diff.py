"""``worldagent diff``: a planted regression (a racing driver and a copy blind to sharp left corners) is
found, located and gated; identical agents differ by exactly 0; bad input is refused before any episode."""

from __future__ import annotations

import dataclasses
import json
import textwrap

import jax.numpy as jnp
import numpy as np
import pytest
from typer.testing import CliRunner

from killed_backend import DiesAfter
from worldagent import differential
from worldagent.agents.policy import Policy
from worldagent.cli import app
from worldagent.envs import registry
from worldagent.envs.racing.driver import DriverParams, driver_action
from worldagent.envs.racing.env import ACTION_DIRECTIONS
from worldagent.errors import WorldagentError
from worldagent.store import Evaluation, RunStore

pytestmark = pytest.mark.integration  # whole diff runs (agents, searches, confirmations): .ci/run's integration step runs it

runner = CliRunner()
SPEC = registry.get("racing")
BLIND_ANGLE = 2.3  # radians of left turn over the next 8 segments beyond which the copy stops steering
HORIZON = 8

# The same pair as host callables on the route observation (position, velocity, 8 route points
# ahead), for the command line: a driver that laps every track, and its copy that, where the route
# ahead turns left by more than 2.2 rad over its first four legs, keeps pushing along its velocity.
CALLABLES = """
import numpy as np

DIRECTIONS = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])


def driver(obs):
    push = obs[:, 6:8] - obs[:, 2:4]  # toward route point 1, against the velocity
    return (push @ DIRECTIONS.T).argmax(axis=1)


def left_turn(obs):
    route = obs[:, 4:].reshape(len(obs), -1, 2)[:, :5]
    heading = np.arctan2(*np.diff(route, axis=1).transpose(2, 0, 1)[::-1])
    return ((np.diff(heading, axis=1) + np.pi) % (2 * np.pi) - np.pi).sum(axis=1)


def blind(obs):
    straight = (obs[:, 2:4] @ DIRECTIONS.T).argmax(axis=1)
    return np.where(left_turn(obs) > 2.2, straight, driver(obs))
"""


def left_turn_ahead(centreline, segment, horizon: int = HORIZON):
    """Signed turning (rad, left positive) of the centreline over ``horizon`` segments from ``segment``."""
    n = centreline.shape[0]
    index = (segment + jnp.arange(horizon + 1)) % n
    edges = centreline[(index + 1) % n] - centreline[index]
    heading = jnp.arctan2(edges[:, 1], edges[:, 0])
    return jnp.sum((jnp.diff(heading) + jnp.pi) % (2 * jnp.pi) - jnp.pi)


def blind_driver(params) -> Policy:
    """The scripted driver, except that before a left turn sharper than ``BLIND_ANGLE`` it pushes
    along its velocity instead of steering (and braking) into the corner."""

    def act(p, obs, key, state):
        straight = jnp.argmax(jnp.asarray(ACTION_DIRECTIONS) @ state.velocity).astype(jnp.int32)
        blind = left_turn_ahead(state.world.centreline, state.segment) > BLIND_ANGLE
        return jnp.where(blind, straight, driver_action(state, *p))

    return Policy((params, DriverParams()), act, "blind driver", privileged=True)


def sharpest_left_corner(centreline: np.ndarray) -> float:
    """The largest left turn (rad) over ``HORIZON`` consecutive segments of a closed centreline (as ``left_turn_ahead``)."""
    edges = np.roll(centreline, -1, axis=0) - centreline
    heading = np.arctan2(edges[:, 1], edges[:, 0])
    turns = (np.roll(heading, -1) - heading + np.pi) % (2 * np.pi) - np.pi  # turn s: from edge s to edge s + 1
    return float(max(np.roll(turns, -s)[:HORIZON].sum() for s in range(len(turns))))


@pytest.fixture(scope="module")
def planted(racing_generator, tmp_path_factory):
    """The scripted driver (A) against its blind copy (B): 128 prior worlds and a 420-world CMA-ES search, the regressed
    and reported worlds confirmed on 8 fresh episodes per agent (the fewest where 8 of 8 crashes is beyond 0.5)."""
    setup = differential.diff_setup("racing", "scripted/driver", blind_driver(SPEC.make_env({})[1]), racing_generator, repeats=1)
    with RunStore(tmp_path_factory.mktemp("planted")) as store:
        result = differential.diff(store, setup, worlds=128, search="cmaes", budget=420, seed=0, progress=False, confirm=8)
        worlds = {(e.slot, e.generation): e.world for e in store.evaluations(with_worlds=True) if e.campaign == result["worlds"]["campaign"]}
    return result, worlds


def test_planted_regression_is_reported_with_intervals_that_exclude_zero(planted):
    result, _ = planted
    found = result["worlds"]
    assert found["worlds"] == 128 and found["episodes"] == 2 * 128 and result["episodes"] == 2 * 128 + 2 * 420
    ret = found["metrics"]["return"]
    assert ret["difference"] < 0 and ret["high"] < 0  # B's return is lower, significantly
    failure = found["failure"]
    assert failure["regressed"] >= 10 and failure["regressed"] > 3 * failure["improved"]
    assert failure["difference"]["low"] > 0 and failure["difference"]["p_value"] < 1e-3
    assert failure["b"]["p"] - failure["a"]["p"] == pytest.approx(failure["difference"]["value"])
    assert found["cvar"]["difference"] < 0 and found["cvar"]["high"] < 0


def test_every_regressed_world_has_a_left_corner_beyond_the_blind_angle(planted):
    result, worlds = planted
    rows = result["worlds"]["regressed_worlds"]
    assert len(rows) == min(20, result["worlds"]["failure"]["regressed"])
    priors = [row["log_prior"] for row in rows]
    assert priors == sorted(priors, reverse=True)  # likeliest first
    for row in rows:
        assert row["b"]["crashed"] > 0.5 >= row["a"]["crashed"]
        assert sharpest_left_corner(worlds[(row["slot"], row["generation"])]["centreline"]) > BLIND_ANGLE - 1e-3
        near = row["nearest_passing"]
        assert near is not None and near["distance"] > 0 and near["slot"] != row["slot"]


def test_differential_search_finds_where_the_blind_copy_crashes_and_the_driver_laps(planted):
    result, _ = planted
    search = result["search"]
    assert search["evaluations"] == 420 and search["first_regressed"] is not None and search["first_regressed"] <= 420
    best = search["best"]
    assert best["score"] < -300 and best["a"] > 0 > best["b"]  # the driver laps (positive return), the copy crashes
    row = search["regressed_worlds"][0]
    assert row["a"]["crashed"] == 0.0 and row["b"]["crashed"] == 1.0
    # CMA-ES on return(B) − return(A) concentrates on the blind spot: more regressed worlds than prior sampling
    assert search["regressed_evaluations"] / search["evaluations"] > 1.5 * result["worlds"]["failure"]["regressed"] / result["worlds"]["worlds"]
    assert search["regressed"] <= search["regressed_evaluations"] and len(search["regressed_worlds"]) == min(20, search["regressed"])


def test_regressed_worlds_are_confirmed_for_both_agents_on_the_same_fresh_episodes(planted):
    result, _ = planted
    for part in (result["worlds"], result["search"]):
        confirmed = part["confirmed"]
        assert confirmed["repeats"] == 8 and confirmed["checked"] == min(50, confirmed["found_regressed"]) >= 1
        assert confirmed["episodes"] == 2 * 8 * confirmed["checked"] and len({row["world"] for row in confirmed["worlds"]}) == confirmed["checked"]
        for row in confirmed["worlds"]:
            assert row["found_regressed"] and row["a"]["found"]["crashed"]["episodes"] == 1 and row["b"]["confirmed"]["crashed"]["episodes"] == 8
            assert row["confirmed_regressed"] == (row["b"]["confirmed_failing"] and row["a"]["confirmed_passing"])
        # the blind spot is in the world: most of its regressed worlds stay regressed on fresh episodes
        assert confirmed["regressed"] >= confirmed["checked"] // 2
    assert result["worlds"]["confirmed"]["found_regressed"] == result["worlds"]["failure"]["regressed_distinct"]
    search = result["search"]
    assert search["confirmed"]["found_regressed"] == search["regressed"]
    assert search["confirmed"]["largest_drop"]["mean"] > 300 and search["confirmed"]["largest_drop"]["episodes"] == 8
    assert result["confirmation_episodes"] >= result["worlds"]["confirmed"]["episodes"] + search["confirmed"]["episodes"]
    from worldagent.analysis.gate import parse_gate, quantities

    gate = parse_gate(["search_regressed > 0"], SPEC.metrics)
    assert quantities(result)["search_regressed"] == search["confirmed"]["regressed"] and gate.check(quantities(result))["failed"]
    from worldagent.reports.diff import markdown

    assert "are confirmed regressed (B's confirmed interval fails" in markdown(result)


def paired(slot: int, a_crashed: float, b_crashed: float) -> Evaluation:
    """A paired evaluation of one episode: A's and B's crash (and return: minus it)."""
    episodes = [{"crashed": b_crashed, "return": -b_crashed, "A.crashed": a_crashed, "A.return": -a_crashed}]
    return Evaluation("diff-cmaes-min-return-s0", 0, slot, np.array([0.1 * slot, 0.0]), a_crashed - b_crashed, episodes, 0.0, 0.0)


def test_a_search_counts_distinct_regressed_worlds_not_evaluations():
    from worldagent.analysis.paired import search_summary
    from worldagent.events import parse_selection

    event = parse_selection("crash_rate > 0.5", "racing")
    track, other = {"road": np.ones(3)}, {"road": np.zeros(3)}
    found = [paired(0, 0.0, 1.0), paired(1, 0.0, 1.0), paired(2, 0.0, 0.0), paired(3, 0.0, 1.0), paired(4, 1.0, 1.0)]
    worlds = [track, track, other, {"road": np.arange(3.0)}, other]  # slots 0 and 1: one track after repair
    found = [dataclasses.replace(e, world=w) for e, w in zip(found, worlds)]
    summary = search_summary(found, SPEC, event, "return", False)
    assert summary["regressed_evaluations"] == 3 and summary["regressed"] == 2
    assert sorted(row["slot"] for row in summary["regressed_worlds"]) == [0, 3]  # one row per distinct world, its first evaluation


def test_a_killed_confirmation_of_both_agents_resumes_to_identical_rows(racing_generator, tmp_path, monkeypatch):
    from worldagent.analysis import confirm as module
    from worldagent.events import parse_selection

    monkeypatch.setattr(module, "BATCH", 2)  # several batches of a few worlds
    setup = differential.diff_setup("racing", "scripted/driver", blind_driver(SPEC.make_env({})[1]), racing_generator, repeats=1)
    event, rows = parse_selection("crash_rate > 0.5", "racing"), {}
    for name, backend in (("straight", None), ("killed", DiesAfter(1))):
        with RunStore(tmp_path / name) as store:
            picks = differential.prior_set(store, setup, 6, progress=False)
            common = dict(name="test", repeats=3, seed=0, progress=False)
            if backend is not None:
                with pytest.raises(KeyboardInterrupt):
                    differential.confirm_worlds(store, dataclasses.replace(setup, backend=backend), picks, event, ["return"], **common)
                assert len(store.confirmations()) == 2  # A's first batch, committed
            confirmed = differential.confirm_worlds(store, setup, picks, event, ["return"], **common)
            rows[name] = sorted((c.agent, c.world, c.seed, c.repeats, str(c.episodes)) for c in store.confirmations())
            assert len({agent for agent, *_ in rows[name]}) == 2  # A and B, each confirmed
            # A and B play the same keys (common random numbers): the same world, seed and repeats for both
            assert all(row["confirmation_seed"] and row["a"]["found"]["return"]["episodes"] == 1 for row in confirmed)
            assert len({row[1:4] for row in rows[name]}) == len(rows[name]) // 2
    assert rows["killed"] == rows["straight"] and len(rows["straight"]) == 2 * len({row[1] for row in rows["straight"]})


@pytest.fixture(scope="module")
def cli_inputs(tmp_path_factory, racing_vae, racing_data, racing_generator):
    """A saved generator and the callables module, in a folder the command runs from."""
    from worldagent.worlds.generator import save_generator

    folder = tmp_path_factory.mktemp("cli")
    (folder / "diff_drivers.py").write_text(textwrap.dedent(CALLABLES))
    generator = save_generator(folder / "gen", racing_vae, racing_data.save(folder / "data.npz"), racing_generator)
    return folder, generator


def run(folder, monkeypatch, *args):
    monkeypatch.chdir(folder)
    return runner.invoke(app, ["diff", "racing", *args])


def test_the_gate_fails_a_planted_regression_and_passes_identical_agents(cli_inputs, monkeypatch, tmp_path):
    folder, generator = cli_inputs
    common = ["--generator", str(generator), "--worlds", "48", "--repeats", "1", "--quiet", "--confirm", "6"]
    gates = ["--fail-if", "p_failure_increase > 0.005", "--fail-if", "regressed > 0", "--fail-if", "return_drop > 2"]
    worse = run(folder, monkeypatch, "--agent", "diff_drivers:driver", "--agent", "diff_drivers:blind", *common, *gates, "--out", str(tmp_path / "w"))
    assert worse.exit_code == 1, worse.output
    found = json.loads((tmp_path / "w" / "diff.json").read_text())
    assert found["gate"]["failed"] and all(row["holds"] for row in found["gate"]["conditions"])
    assert found["worlds"]["failure"]["regressed"] > 0 and found["worlds"]["failure"]["improved"] == 0
    assert found["agents"]["b"] == {"kind": "callable", "path": "diff_drivers:blind", "sha256": found["agents"]["a"]["sha256"]}
    report = (tmp_path / "w" / "diff.md").read_text()
    assert report.startswith("## Which worlds got worse? (racing)") and "Gate: **failed**" in report and "regressed (fail under B" in report

    same = run(folder, monkeypatch, "--agent", "diff_drivers:driver", "--agent", "diff_drivers:driver", *common, *gates, "--out", str(tmp_path / "s"))
    assert same.exit_code == 0, same.output
    found = json.loads((tmp_path / "s" / "diff.json").read_text())
    assert not found["gate"]["failed"]
    for row in found["worlds"]["metrics"].values():
        assert row["difference"] == 0.0 and row["low"] == row["high"] == 0.0
    failure = found["worlds"]["failure"]
    assert failure["difference"]["value"] == 0.0 and failure["regressed"] == failure["improved"] == 0
    assert found["worlds"]["cvar"]["difference"] == 0.0 and found["worlds"]["regressed_worlds"] == []
    again = run(folder, monkeypatch, "--agent", "diff_drivers:driver", "--agent", "diff_drivers:driver", *common, "--out", str(tmp_path / "s"))
    assert again.exit_code == 0 and json.loads((tmp_path / "s" / "diff.json").read_text())["worlds"] == found["worlds"]  # a rerun resumes


@pytest.mark.integration
def test_worlds_from_a_stored_campaign_a_dataset_and_an_atlas_search(cli_inputs, monkeypatch, tmp_path, racing_data):
    folder, generator = cli_inputs
    agents = ["--agent", "scripted/driver", "--agent", "diff_drivers:blind", "--repeats", "1", "--quiet", "--confirm", "6"]
    searched = run(
        folder,
        monkeypatch,
        *agents,
        "--generator",
        str(generator),
        "--search",
        "atlas",
        "--budget",
        "42",
        "--cells",
        "3",
        "--out",
        str(tmp_path / "a"),
    )
    assert searched.exit_code == 0, searched.output
    atlas = json.loads((tmp_path / "a" / "diff.json").read_text())["search"]
    assert atlas["campaign"] == "diff-atlas-min-return-s0" and atlas["evaluations"] == 42
    from worldagent.search.atlas import atlas_names

    with RunStore(tmp_path / "a", create=False) as store:
        assert atlas_names(store) == ["diff-atlas-min-return-s0"]  # the explorer's Atlas view shows it
    stored = run(folder, monkeypatch, *agents, "--campaign", "diff-atlas-min-return-s0", "--store", str(tmp_path / "a"), "--out", str(tmp_path / "c"))
    assert stored.exit_code == 0, stored.output
    from_campaign = json.loads((tmp_path / "c" / "diff.json").read_text())
    assert from_campaign["worlds"]["worlds"] == 42 and from_campaign["source"]["campaign"] == "diff-atlas-min-return-s0"
    # the same worlds and keys: the set comparison agrees with what the search measured
    assert from_campaign["worlds"]["failure"]["regressed"] == atlas["regressed_evaluations"]
    assert from_campaign["worlds"]["failure"]["regressed_distinct"] == atlas["regressed"] == atlas["confirmed"]["found_regressed"]

    small = racing_data.subset(np.arange(12)).save(tmp_path / "twelve.npz")
    listed = run(folder, monkeypatch, *agents, "--dataset", str(small), "--dataset", str(small), "--out", str(tmp_path / "d"))
    assert listed.exit_code == 0, listed.output
    from_data = json.loads((tmp_path / "d" / "diff.json").read_text())["worlds"]
    assert from_data["worlds"] == 24 and all(row["log_prior"] is None for row in from_data["regressed_worlds"])
    assert from_data["failure"]["regressed"] % 2 == 0  # each file's worlds twice, each played alike


def test_bad_input_is_refused_in_one_line_before_any_episode(cli_inputs, monkeypatch, tmp_path):
    folder, generator = cli_inputs
    two = ["--agent", "scripted/driver", "--agent", "diff_drivers:blind", "--out", str(tmp_path / "x")]
    cases = [
        (["--agent", "scripted/driver", "--generator", str(generator), "--worlds", "4"], "pass it twice"),
        ([*two, "--generator", str(generator), "--worlds", "4", "--fail-if", "speed_drop > 1"], "unknown metric 'speed'"),
        ([*two, "--generator", str(generator), "--worlds", "4", "--fail-if", "regressed >"], "expected QUANTITY OP NUMBER"),
        ([*two, "--generator", str(generator), "--worlds", "4", "--fail-if", "search_regressed > 0"], "add --search"),
        ([*two, "--generator", str(generator), "--worlds", "4", "--dataset", "x.npz"], "compare on one world set"),
        ([*two, "--worlds", "4"], "need --generator"),
        ([*two], "nothing to compare on"),
        ([*two, "--campaign", "random-return-s0"], "--campaign and --store go together"),
        ([*two, "--generator", str(generator), "--search", "bo"], "use one of: cmaes, atlas"),
        ([*two, "--generator", str(generator), "--worlds", "0"], "--worlds is 0"),
        ([*two, "--generator", str(generator), "--worlds", "4", "--failure", "speed > 1"], "unknown racing metric 'speed'"),
    ]
    for args, message in cases:
        result = run(folder, monkeypatch, *args)
        lines = result.output.strip().splitlines()
        assert result.exit_code == 2 and len(lines) == 1 and message in result.output, (args, result.output)
    assert not (tmp_path / "x").exists()  # refused before anything ran or was written


def test_a_store_written_by_other_agents_is_not_mixed_in(racing_generator, tmp_path):
    params = SPEC.make_env({})[1]
    with RunStore(tmp_path) as store:
        first = differential.diff_setup("racing", "scripted/driver", blind_driver(params), racing_generator, repeats=1)
        differential.prior_set(store, first, 4, progress=False)
        other = differential.diff_setup("racing", "scripted/driver", "scripted/random", racing_generator, repeats=1)
        for count in (2, 8):  # never the first pair's evaluations, whether they would suffice or not
            with pytest.raises(WorldagentError, match="compared other agents"):
                differential.prior_set(store, other, count, progress=False)
        assert len(differential.prior_set(store, first, 6, progress=False)) == 6  # the same pair resumes
