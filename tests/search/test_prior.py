"""The prior's typical set (issue 48): its pure functions, and campaigns that stay inside it, record it and refuse another."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2, multivariate_normal

from worldagent.errors import WorldagentError
from worldagent.search import prior
from worldagent.search.campaign import CampaignSpec, Outcome, run_campaign, searched_where
from worldagent.search.names import describe_campaign
from worldagent.search.optimisers import OptimiserConfig, make_optimiser, within_prior_config
from worldagent.store import RunStore

CONFIG = OptimiserConfig(popsize=6, bo_batch=3, initial_points=4, bo_candidates=500, bo_starts=1, random_batch=6)
AXIS = np.eye(10)[0]


def along_axis(z, seeds):
    """Maximised by pushing z_0 out: the optimum lies on the boundary of any bound."""
    return [Outcome(float(latent @ AXIS), [{"v": float(latent @ AXIS)}]) for latent in z]


def spec(optimiser="cmaes", budget=60, **kw):
    return CampaignSpec("c", "racing", "v", True, optimiser, budget, 1, 10, CONFIG, **kw)


def norms(evaluations):
    return np.linalg.norm([e.latent for e in evaluations], axis=1)


def test_the_typical_radius_is_the_chi_quantile_and_holds_its_share_of_prior_draws():
    assert prior.typical_radius(10) == pytest.approx(5.4395, abs=1e-4)
    assert prior.norm_percentile(prior.typical_radius(10), 10) == pytest.approx(prior.TYPICAL_MASS)
    draws = np.random.default_rng(0).standard_normal((200_000, 10))
    assert np.mean(prior.latent_norm(draws) <= prior.typical_radius(10)) == pytest.approx(0.999, abs=3e-4)
    assert prior.typical_radius(2) < prior.typical_radius(10) < prior.typical_radius(32)
    with pytest.raises(WorldagentError, match="mass in"):
        prior.typical_radius(10, 1.0)


def test_log_prior_is_the_standard_normal_density_and_its_typical_value_the_mean():
    z = np.random.default_rng(1).standard_normal((50_000, 10))
    assert np.allclose(prior.log_prior(z[:5]), multivariate_normal(np.zeros(10), np.eye(10)).logpdf(z[:5]))
    assert prior.log_prior(z).mean() == pytest.approx(prior.typical_log_prior(10), abs=0.05)


def test_the_tail_stays_finite_far_beyond_the_prior_and_joins_the_exact_one():
    assert prior.norm_tail_log10(6.0, 10) == pytest.approx(chi2.logsf(36.0, 10) / math.log(10))
    far = prior.norm_tail_log10(np.array([37.0, 38.0, 41.8]), 10)
    assert np.all(np.isfinite(far)) and np.all(np.diff(far) < 0)
    assert far[0] == pytest.approx(chi2.logsf(37.0**2, 10) / math.log(10), rel=1e-3)  # exact where it still exists


def test_within_ball_projects_radially_and_leaves_the_inside_alone():
    z = np.array([[0.3, -0.4], [6.0, 8.0], [0.0, 0.0]])
    inside = prior.within_ball(z, 5.0)
    assert np.array_equal(inside[0], z[0]) and np.array_equal(inside[2], z[2])
    assert np.allclose(inside[1], [3.0, 4.0])  # |z| = 10 -> 5, the same direction
    assert np.array_equal(prior.within_ball(z, None), z)


def test_a_bound_is_typical_none_or_a_radius_and_nothing_else():
    assert prior.prior_bound("typical", 10) == prior.typical_radius(10)
    assert prior.prior_bound("none", 10) is None and prior.prior_bound(None, 10) is None
    assert prior.prior_bound("4.5", 10) == 4.5
    for bad in ("wide", "-1", "0", "nan"):
        with pytest.raises(WorldagentError, match="--prior-bound"):
            prior.prior_bound(bad, 10)


def test_a_latent_in_words_says_its_percentile_or_its_tail():
    typical = prior.prior_text(np.full(10, 1.0))
    assert typical.startswith("|z| 3.16 (56th percentile") and "outside" not in typical
    far = prior.prior_text(41.8 * AXIS)
    assert "P(|z'| >= |z|) = 1e-369" in far and "outside the typical set |z| <= 5.44" in far
    assert prior.ordinal(99.96) == "99.96th" and prior.ordinal(2.4) == "2nd" and prior.ordinal(12) == "12th"


def test_bo_runs_in_the_box_that_holds_the_ball_and_cmaes_without_one():
    radius = prior.typical_radius(10)
    assert within_prior_config("bo", CONFIG, radius).bound == radius
    assert within_prior_config("cmaes", CONFIG, radius).bound == 0.0
    assert within_prior_config("cmaes", CONFIG, None) == CONFIG


@pytest.mark.parametrize("optimiser, budget", [("cmaes", 60), ("bo", 10)])
def test_a_search_stays_in_the_typical_set_by_default_and_reaches_its_edge(tmp_path, optimiser, budget):
    with RunStore(tmp_path) as store:
        found = run_campaign(store, spec(optimiser, budget), along_axis, progress=False)
        campaign = store.campaign("c")
    radius = prior.typical_radius(10)
    assert np.all(norms(found) <= radius + 1e-9)  # the stored latents are the evaluated ones, all inside
    assert max(e.score for e in found) > 3.0  # past the old box |z_i| <= 3, towards the ball's edge
    assert campaign.config["prior_bound"] == pytest.approx(radius)
    assert "within |z| <= 5.44" in describe_campaign(campaign, "c") and searched_where(campaign).startswith("searched within")


def test_beyond_the_prior_the_search_leaves_the_ball(tmp_path):
    with RunStore(tmp_path) as store:
        found = run_campaign(store, spec(prior_bound=None), along_axis, progress=False)
        assert store.campaign("c").config["prior_bound"] is None
        assert "beyond the prior" in describe_campaign(store.campaign("c"), "c")
    assert norms(found).max() > prior.typical_radius(10)


def test_resuming_with_another_bound_is_refused_in_one_line_and_with_the_same_one_replays(tmp_path):
    with RunStore(tmp_path) as store:
        first = run_campaign(store, spec(budget=12), along_axis, progress=False)
        with pytest.raises(WorldagentError, match=r"searched within \|z\| <= 5.44 .*not beyond the prior.*--prior-bound typical,") as refused:
            run_campaign(store, spec(budget=24, prior_bound=None), along_axis, resume=True, progress=False)
        assert "\n" not in str(refused.value)
        again = run_campaign(store, spec(budget=24), along_axis, resume=True, progress=False)
    assert [e.latent.tolist() for e in again[:12]] == [e.latent.tolist() for e in first]


def test_a_campaign_stored_before_bounds_resumes_as_it_was_searched(tmp_path):
    with RunStore(tmp_path) as store:
        run_campaign(store, spec(budget=12, prior_bound=None), along_axis, progress=False)
        config = {k: v for k, v in store.campaign("c").config.items() if k != "prior_bound"}  # as stored before bounds
        store.db.execute("UPDATE campaigns SET config=? WHERE name='c'", (__import__("json").dumps(config),))
        store.db.commit()
        resumed = run_campaign(store, spec(budget=60), along_axis, resume=True, progress=False)  # asked the default bound
        assert "prior_bound" not in store.campaign("c").config and searched_where(store.campaign("c")).startswith("searched beyond")
    assert norms(resumed).max() > prior.typical_radius(10)  # unbounded, as it began


def test_random_search_keeps_the_priors_draws_and_records_no_bound(tmp_path):
    with RunStore(tmp_path) as store:
        found = run_campaign(store, spec("random", 12), along_axis, progress=False)
        assert "prior_bound" not in store.campaign("c").config and searched_where(store.campaign("c")) == "drawn from the prior"
    draws = make_optimiser("random", 10, True, 1, CONFIG)
    expected = np.vstack([draws.ask(6), draws.ask(6)])
    assert np.array_equal(np.array([e.latent for e in found]), expected)


def test_noise_aware_cmaes_re_asks_the_evaluated_incumbents_inside_the_ball(tmp_path):
    config = OptimiserConfig(popsize=8)
    with RunStore(tmp_path) as store:
        found = run_campaign(store, CampaignSpec("c", "racing", "v", True, "cmaes-re", 40, 1, 10, config), along_axis, progress=False)
    latents = [tuple(e.latent) for e in found]
    assert len(set(latents)) < len(latents)  # incumbents were played again, at the latents stored
    assert np.all(norms(found) <= prior.typical_radius(10) + 1e-9)


def test_the_report_and_the_diff_say_where_a_found_world_lies():
    from worldagent.reports.diff import search_lines
    from worldagent.reports.html import prior_cell

    far = prior.prior_summary(5.9 * AXIS)
    cell = prior_cell("racing.min.latent_norm", far)
    assert 'data-value="5.9"' in cell and "5.9 (99.98th pct)" in cell
    assert "(tail 1e-369)" in prior_cell("k", prior.prior_summary(41.8 * AXIS))
    assert prior_cell("k", None) == "<td>–</td>"
    best = {"campaign": "c", "generation": 0, "slot": 0, "score": -1.0, "a": 1.0, "b": 0.0, "prior": far}
    search = {"best": best, "maximize": False, "first_regressed": None, "regressed": 0, "search": "cmaes", "campaign": "c"}
    lines = search_lines({**search, "evaluations": 21, "episodes": 336, "metric": "return", "prior_bound": None})
    assert "Under the prior: |z| 5.9 (99.98th percentile" in lines[2] and "searched beyond the prior" in lines[2]


@pytest.mark.slow  # ~15 s on loaded cores (episodes of 21 worlds); the pieces it prints are tested fast above
def test_the_search_command_reports_z_and_refuses_to_resume_across_bounds(tmp_path, racing_vae, racing_data, racing_generator):
    from typer.testing import CliRunner

    from worldagent.cli import app
    from worldagent.worlds.generator import save_generator

    runner = CliRunner()
    gen = save_generator(tmp_path / "gen", racing_vae, racing_data.save(tmp_path / "data.npz"), racing_generator)
    search = ["search", "racing", "--agent", "driver", "--generator", str(gen), "--out", str(tmp_path / "run"), "--repeats", "2", "--quiet"]
    search += ["--budget", "21", "--confirm", "0"]
    result = runner.invoke(app, search)
    assert result.exit_code == 0, result.output
    assert "max world under the prior: |z| " in result.output and "searched within |z| <= 5.44" in result.output
    refused = runner.invoke(app, [*search, "--resume", "--prior-bound", "none"])
    assert refused.exit_code == 2 and "resume it with --prior-bound typical" in refused.output
    bad = runner.invoke(app, [*search, "--prior-bound", "wide"])
    assert bad.exit_code == 2 and "--prior-bound 'wide'" in bad.output


def test_a_campaign_searched_within_another_radius_names_it_to_resume(tmp_path):
    with RunStore(tmp_path) as store:
        run_campaign(store, spec(budget=12, prior_bound=4.0), along_axis, progress=False)
        with pytest.raises(WorldagentError, match=r"resume it with --prior-bound 4,"):
            run_campaign(store, spec(budget=24), along_axis, resume=True, progress=False)
        assert np.all(norms(run_campaign(store, spec(budget=24, prior_bound="4"), along_axis, resume=True, progress=False)) <= 4.0 + 1e-12)


def test_compare_searches_every_optimiser_within_the_bound_it_is_given(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from worldagent import experiments
    from worldagent.cli import app

    asked = []
    monkeypatch.setattr(experiments, "search", lambda *args, **kw: (asked.append((kw["optimiser"], kw["prior_bound"])), ([], None))[1])
    setup = type("Setup", (), {"metric": lambda self, name: name})()
    experiments.compare_optimisers(None, setup, "return", optimisers=("cmaes", "random"), budget=6, seeds=(0,), prior_bound=None)
    experiments.compare_optimisers(None, setup, "return", optimisers=("bo",), budget=6, seeds=(0, 1))
    assert asked == [("cmaes", None), ("random", None), ("bo", prior.TYPICAL), ("bo", prior.TYPICAL)]
    bad = CliRunner().invoke(app, ["compare", "racing", "--agent", "driver", "--generator", str(tmp_path), "--prior-bound", "wide"])
    assert bad.exit_code == 2 and "--prior-bound 'wide'" in bad.output
