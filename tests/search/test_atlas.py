"""The failure atlas: grid bookkeeping, descriptors, CMA-ME campaigns that resume, the command."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
from typer.testing import CliRunner

from worldagent import experiments
from worldagent.cli import app
from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.search.atlas import (
    Grid,
    archive_of,
    atlas_names,
    cell_of,
    check_descriptors,
    distinct_count,
    grid_ranges,
    read_atlas,
)
from worldagent.search.corrected_atlas import corrected_summary, stored_elites
from worldagent.store import Evaluation, RunStore

GRID = Grid(("a", "b"), (2, 3), ((0.0, 1.0), (0.0, 3.0)))


def test_cells_are_row_major_and_values_outside_the_ranges_land_on_the_edges():
    measures = np.array([[0.1, 0.5], [0.9, 2.5], [-5.0, 99.0], [0.5, 1.0]])
    np.testing.assert_array_equal(cell_of(GRID, measures), [0, 5, 2, 4])


def test_each_cell_keeps_its_best_world_the_earliest_on_ties_and_no_nan():
    measures = np.array([[0.1, 0.5], [0.2, 0.4], [0.1, 0.6], [0.9, 2.5], [0.9, 2.6]])
    scores = np.array([3.0, 1.0, 1.0, np.nan, 7.0])
    low = archive_of(GRID, scores, measures, maximize=False)
    np.testing.assert_array_equal(low.cells, [0, 5])
    np.testing.assert_array_equal(low.best, [1, 4])  # 1.0 twice in cell 0: the earlier; NaN ignored in cell 5
    assert low.coverage(GRID) == pytest.approx(2 / 6)
    assert low.qd_score(offset=10.0, maximize=False) == pytest.approx((10 - 1) + (10 - 7))
    high = archive_of(GRID, scores, measures, maximize=True)
    np.testing.assert_array_equal(high.best, [0, 4])


def test_distinct_worlds_are_counted_by_content():
    a, b = {"x": np.arange(3)}, {"x": np.arange(3) + 1}
    assert distinct_count([a, dict(a), b]) == 2


def test_racing_descriptors_on_hand_made_tracks():
    spec = registry.get("racing")
    angle = np.linspace(0, 2 * np.pi, 256, endpoint=False)
    circle = SimpleNamespace(centreline=np.stack([0.5 * np.cos(angle), 0.5 * np.sin(angle)], axis=1))
    square = SimpleNamespace(
        centreline=np.array(
            [[x, -0.5] for x in np.linspace(-0.5, 0.5, 64, endpoint=False)]
            + [[0.5, y] for y in np.linspace(-0.5, 0.5, 64, endpoint=False)]
            + [[x, 0.5] for x in np.linspace(0.5, -0.5, 64, endpoint=False)]
            + [[-0.5, y] for y in np.linspace(0.5, -0.5, 64, endpoint=False)]
        )
    )
    describe = spec.metrics.descriptors
    assert describe["total_curvature"](circle) == pytest.approx(2 * np.pi, rel=1e-6)
    assert describe["total_curvature"](square) == pytest.approx(2 * np.pi, rel=1e-6)
    assert describe["sharpest_corner"](square) == pytest.approx(np.pi / 2, rel=1e-6)
    assert describe["sharpest_corner"](circle) < 0.5
    assert describe["track_length"](circle) == pytest.approx(np.pi, rel=1e-3)
    assert describe["track_length"](square) == pytest.approx(4.0, rel=1e-6)


def test_harvest_descriptors_on_hand_made_maps():
    from worldagent.envs.harvest.world import HarvestMap

    describe = registry.get("harvest").metrics.descriptors
    block = HarvestMap.from_str("AA...\nAA...\n..#..\n.....")  # 4 apples, each with 3 apple neighbours; 1 wall of 20 cells
    scattered = HarvestMap.from_str("A...A\n.....\n.....\nA...A")  # 4 apples, none next to another
    walled = HarvestMap.from_str("..#..\n###..\n.....\n.....")  # the tagger's corner is closed off from every other
    assert describe["apple_clustering"](block) == 3.0 and describe["apple_clustering"](scattered) == 0.0
    assert describe["wall_share"](block) == pytest.approx(1 / 20) and describe["wall_share"](walled) == pytest.approx(4 / 20)
    assert describe["tagger_isolated"](walled) == 1.0 and describe["tagger_separated"](block) == 0.0
    # walks to the nearest apple from TL, TR, BL, BR: 0, 3, 2 and 5 (around the wall); a spawn with none in reach: H + W
    assert describe["apple_distance"](block) == 2.5 and describe["apple_distance"](scattered) == 0.0
    walled_apple = HarvestMap.from_str("..#..\n###..\n.....\n...A.")
    assert describe["apple_distance"](walled_apple) == (9 + 4 + 3 + 1) / 4
    assert describe["largest_patch"](block) == 4.0 and describe["largest_patch"](scattered) == 1.0 and describe["largest_patch"](walled) == 0.0


def test_bad_atlas_input_gets_one_line_errors():
    spec = registry.get("racing")
    for names, cells, budget, message in [
        (("curvy",), 10, 2100, "unknown descriptor 'curvy' for racing; use some of: total_curvature"),
        (("total_curvature", "total_curvature"), 10, 2100, "pick 1 to 3 different ones"),
        (None, 10, 42, "--budget 42 is smaller than the grid's 100 cells"),
        (None, 1, 2100, "at least 2 cells"),
    ]:
        with pytest.raises(WorldagentError, match=message) as error:
            check_descriptors(spec, names, cells, budget)
        assert "\n" not in str(error.value)
    assert check_descriptors(spec, None, 5, 100) == (("total_curvature", "sharpest_corner"), (5, 5))


def test_a_killed_atlas_resumes_to_the_same_archive(tmp_path, racing_generator):
    setup = experiments.setup("racing", "driver", racing_generator, repeats=1)
    common = dict(maximize=False, seed=1, cells=4, progress=False, failure="return < 50", confirm=2)
    with RunStore(tmp_path / "whole") as store:
        whole = experiments.atlas(store, setup, "reward", budget=63, **common)
    with RunStore(tmp_path / "killed") as store:
        experiments.atlas(store, setup, "reward", budget=21, **{**common, "confirm": 0})  # stopped after one generation
        resumed = experiments.atlas(store, setup, "reward", budget=63, **common)
    assert resumed["confirmed"] == whole["confirmed"] and whole["confirmed"]["elites"] == len(whole["archive"].cells)
    assert len(resumed["evaluations"]) == len(whole["evaluations"]) == 63
    assert [e.latent.tolist() for e in resumed["evaluations"]] == [e.latent.tolist() for e in whole["evaluations"]]
    np.testing.assert_array_equal(resumed["archive"].cells, whole["archive"].cells)
    np.testing.assert_array_equal(resumed["archive"].scores, whole["archive"].scores)
    assert resumed["coverage"] > 0.25 and resumed["distinct_failing"] == whole["distinct_failing"]
    with RunStore(tmp_path / "whole") as store:
        assert store.campaign("atlas-min-return-s1").config["atlas"]["grid"]["descriptors"] == ["total_curvature", "sharpest_corner"]
        # read back with no agent and no generator: the archive the search built
        assert atlas_names(store) == ["atlas-min-return-s1"]
        stored = read_atlas(store, "atlas-min-return-s1")
        np.testing.assert_array_equal(stored.archive.cells, whole["archive"].cells)
        np.testing.assert_allclose(stored.archive.measures, whole["archive"].measures)
        assert stored.grid == whole["grid"] and len(stored.cell_table()) == len(whole["archive"].cells)
        with pytest.raises(WorldagentError, match="not an atlas campaign"):
            read_atlas(store, "random-return-s0")


def test_the_atlas_command_draws_the_archive(tmp_path, racing_vae, racing_data, racing_generator):
    from PIL import Image

    from worldagent.worlds.generator import save_generator

    gen = save_generator(tmp_path / "gen", racing_vae, racing_data.save(tmp_path / "data.npz"), racing_generator)
    args = ["atlas", "racing", "--agent", "driver", "--generator", str(gen), "--budget", "42", "--cells", "3", "--repeats", "1"]
    result = CliRunner().invoke(app, [*args, "--failure", "crash_rate > 0.5", "--out", str(tmp_path / "run"), "--quiet", "--confirm", "2"])
    assert result.exit_code == 0, result.output
    assert "atlas-min-return-s0: 42 worlds on a 3x3 grid of total_curvature, sharpest_corner" in result.output
    assert "corrected archive (" in result.output and "failing cells (crash_rate (crashed) > 0.5): found " in result.output
    written = json.loads((tmp_path / "run" / "atlas-min-return-s0.json").read_text())
    assert written["confirmed"]["repeats"] == 2 and len(written["confirmed"]["cells"]) == written["confirmed"]["elites"] >= 1
    assert written["found"]["coverage"] == written["confirmed"]["found"]["coverage"]
    assert Image.open(tmp_path / "run" / "atlas-min-return-s0.png").size[0] > 800
    bad = CliRunner().invoke(app, [*args, "--descriptors", "wall_share", "--out", str(tmp_path / "bad")])
    assert bad.exit_code == 2 and "unknown descriptor 'wall_share' for racing" in bad.output


def test_failures_are_explained_by_nearest_passing_worlds_and_groups(tmp_path, racing_generator):
    from worldagent.evaluation.trajectories import scored_keys
    from worldagent.reports.atlas import counterfactual_figure

    setup = experiments.setup("racing", "driver", racing_generator, repeats=2)
    with RunStore(tmp_path) as store:
        found = experiments.atlas(store, setup, "reward", budget=42, seed=0, cells=3, progress=False, confirm=0)
    median = float(np.median([e.score for e in found["evaluations"]]))
    failure = experiments.failure_selection(f"return < {median}", "racing")
    explained = experiments.explain_failures(setup, found, failure, count=2)
    assert sum(len(c.members) for c in explained["clusters"]) == len(explained["failing"]) >= 1
    assert 1 <= len(explained["pairs"]) <= 2
    for pair in explained["pairs"]:
        edge = pair["boundary"]
        assert 0.0 <= edge.t_failing < edge.t_passing <= 1.0 and edge.evaluated == 21
        # with the failing world's own episodes, its end of the bracket fails and the other passes
        z = np.stack([edge.failing, edge.passing])
        outcomes = experiments.LatentObjective(
            experiments.Objective("racing", "return", True), setup.env, setup.policy, setup.generator, 2, setup.params
        )(z, np.full(2, pair["seed"]))
        np.testing.assert_array_equal(failure.mask(outcomes), [True, False])
        assert len(scored_keys(pair["seed"], 2)) == 2
    assert counterfactual_figure(setup, explained["pairs"], tmp_path / "pairs.png").stat().st_size > 10_000


def test_a_descriptor_constant_on_decoded_worlds_is_refused_with_where_to_look():
    def describe(z):  # the first descriptor varies with z; the second is 0 on every decoded world
        return np.stack([z[:, 0], np.zeros(len(z))], axis=1)

    assert grid_ranges(lambda z: describe(z)[:, :1], 3, ["x"])[0][0] < 0
    with pytest.raises(WorldagentError, match=r"'wall_count' is 0 on all 512 worlds G\(z\) decoded.*worldagent check ENV --generator DIR"):
        grid_ranges(describe, 3, ["x", "wall_count"])


def elite(slot: int, crashed: int, episodes: int, value: float) -> Evaluation:
    """An evaluation of ``episodes`` episodes, ``crashed`` of them crashed, each of return ``value``."""
    rows = [{"return": value, "crashed": float(i < crashed)} for i in range(episodes)]
    return Evaluation("atlas-min-return-s0", 0, slot, np.zeros(2), value, rows, 0.0, 0.0)


def test_the_corrected_archive_rescores_every_elite_and_counts_failing_cells_found_and_confirmed():
    from worldagent.analysis.confirm import ConfirmedWorld

    event = experiments.failure_selection("crash_rate > 0.5", "racing")
    measures = np.array([[0.1, 0.5], [0.9, 2.5], [0.6, 1.5], [0.1, 1.5]])
    found = [elite(0, 8, 8, -100.0), elite(1, 6, 8, -50.0), elite(2, 2, 8, 10.0), elite(3, 8, 8, -80.0)]
    archive = archive_of(GRID, np.array([e.score for e in found]), measures, maximize=False)
    np.testing.assert_array_equal(archive.cells, [0, 1, 4, 5])  # slots 0, 3, 2, 1
    fresh = {  # slot: (crashed of 32, return, digest); slots 0 and 3 are one world after repair
        0: (30, -90.0, "a" * 64),
        3: (29, -85.0, "a" * 64),
        1: (17, -40.0, "b" * 64),  # 17/32 = 0.53, interval [0.35, 0.71]: past 0.5 on average, not beyond doubt
        2: (0, 20.0, "c" * 64),
    }
    confirmed = [ConfirmedWorld(found[int(i)], fresh[int(i)][2], elite(9, fresh[int(i)][0], 32, fresh[int(i)][1]).episodes, 7) for i in archive.best]
    summary = corrected_summary(GRID, archive, confirmed, "return", 20.0, False, event)
    assert summary["elites"] == 4 and summary["distinct_worlds"] == 3 and summary["episodes"] == 3 * 32
    assert summary["found"]["qd_score"] == pytest.approx(120 + 100 + 10 + 70)
    assert summary["confirmed"]["qd_score"] == pytest.approx(110 + 105 + 0 + 60)
    assert summary["found"]["coverage"] == summary["confirmed"]["coverage"] == pytest.approx(4 / 6)  # no elite changes cell
    assert summary["found"]["failing_cells"] == 3 and summary["found"]["failing_worlds"] == 2  # cells 0, 1 (one world) and 5
    assert summary["confirmed"]["failing_cells"] == 2 and summary["confirmed"]["failing_worlds"] == 1
    assert summary["no_longer_failing"] == [5]
    cell = {row["cell"]: row for row in summary["cells"]}[5]
    assert cell["confirmed_failure_rate"]["mean"] > 0.5 and cell["confirmed_failure_rate"]["low"] < 0.5 and not cell["confirmed_failing"]
    assert cell["found"]["return"]["mean"] == -50.0 and cell["confirmed"]["return"]["mean"] == -40.0
    unscored = [*confirmed[:3], ConfirmedWorld(confirmed[3].selected, "d" * 64, [], 7)]  # no finite fresh value: the cell drops out
    assert corrected_summary(GRID, archive, unscored, "return", 20.0, False)["confirmed"]["coverage"] == pytest.approx(3 / 6)
    with pytest.raises(WorldagentError, match="confirm every elite"):
        corrected_summary(GRID, archive, confirmed[:2], "return", 20.0, False)


def test_atlas_elites_are_confirmed_on_keys_no_search_drew_and_read_back_without_an_agent(tmp_path, racing_generator):
    import jax

    from worldagent.analysis.confirm import agent_key, confirmation_keys
    from worldagent.search.campaign import stored_seed
    from worldagent.search.objectives import search_keys

    def key_data(keys):
        return {tuple(int(x) for x in row) for row in np.asarray(jax.random.key_data(keys)).reshape(len(keys), -1)}

    setup = experiments.setup("racing", "driver", racing_generator, repeats=2)
    with RunStore(tmp_path) as store:
        found = experiments.atlas(store, setup, "reward", budget=21, seed=3, cells=2, failure="crash_rate > 0.5", progress=False, confirm=3)
        confirmed, name = found["confirmed"], found["evaluations"][0].campaign
        campaign = store.campaign(name)
        searched = set().union(*(key_data(search_keys(stored_seed(campaign, e.generation, e.slot), 2)) for e in found["evaluations"]))
        fresh = set().union(*(key_data(confirmation_keys(row["confirmation_seed"], 3)) for row in confirmed["cells"]))
        assert len(searched) == 21 * 2 and len(fresh) == 3 * confirmed["distinct_worlds"] and searched.isdisjoint(fresh)
        assert len(store.selections(f"atlas:{name}")) == confirmed["elites"] == len(found["archive"].cells)
        assert len(store.confirmations()) == confirmed["distinct_worlds"] and confirmed["episodes"] == 3 * confirmed["distinct_worlds"]
        # the report's path: the stored confirmations re-read with no agent give the same corrected archive
        atlas = read_atlas(store, name)
        elites = stored_elites(store, atlas, agent_key(setup), 3, 3)
        again = corrected_summary(
            atlas.grid, atlas.archive, elites, "return", found["qd_offset"], False, experiments.failure_selection("crash_rate > 0.5", "racing")
        )
        assert again == confirmed
        assert stored_elites(store, atlas, agent_key(setup), 3, 4) is None  # other repeats: not confirmed
