"""Failure probability: exact binomial intervals, Monte Carlo and importance sampling on a closed-form
Gaussian toy, resuming through the run store, one-line errors, and the CLI end to end."""

from __future__ import annotations

import json
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np
import pytest
from typer.testing import CliRunner

from worldagent.analysis import cross_entropy, mixtures, stored, surrogate
from worldagent.analysis import failure_rate as fr
from worldagent.analysis.stored import failure_names, read_estimate
from worldagent.cli import app
from worldagent.commands.failure_rate import estimate_line
from worldagent.errors import WorldagentError
from worldagent.events import parse_selection
from worldagent.store import RunStore

THRESHOLD = 3.0
P_TOY = 1 - NormalDist().cdf(THRESHOLD)  # P(z[0] > 3) for z ~ N(0, I): 1.35e-3
Z95 = NormalDist().inv_cdf(0.975)


def toy(z: np.ndarray, seeds: np.ndarray) -> fr.Scored:
    """The event z[0] > 3, its margin z[0] - 3, one episode per world."""
    return fr.Scored(z[:, 0] - THRESHOLD, z[:, 0] > THRESHOLD, len(z))


def one_line(error: pytest.ExceptionInfo) -> str:
    message = str(error.value)
    assert "\n" not in message and message.endswith("."), message
    return message


# -- intervals -------------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 10, 1000])
def test_clopper_pearson_closed_forms_at_the_ends(n):
    assert fr.clopper_pearson(0, n) == (0.0, pytest.approx(1 - 0.025 ** (1 / n), rel=1e-9))
    assert fr.clopper_pearson(n, n) == (pytest.approx(0.025 ** (1 / n), rel=1e-9), 1.0)


def test_clopper_pearson_textbook_values_and_symmetry():
    assert fr.clopper_pearson(5, 10) == pytest.approx((0.187086, 0.812914), abs=1e-6)
    assert fr.clopper_pearson(1, 100) == pytest.approx((0.000253, 0.054459), abs=1e-6)
    low, high = fr.clopper_pearson(3, 40, confidence=0.9)
    mirrored = fr.clopper_pearson(37, 40, confidence=0.9)
    assert (low, high) == pytest.approx((1 - mirrored[1], 1 - mirrored[0]), abs=1e-12)
    assert fr.clopper_pearson(3, 40, confidence=0.99)[1] > high  # more confidence, wider


@pytest.mark.parametrize(
    "proposal",
    [
        mixtures.Proposal.shift(np.array([3.0, -1.0])),
        mixtures.Proposal(np.array([[3.0, -1.0], [-2.5, 0.5]]), np.array([0.7, 0.3]), np.array([0.7, 1.0])),
    ],
)
def test_weights_are_bounded_by_the_prior_share_and_ess_counts_equal_weights(proposal):
    z = mixtures.sample_mixture(np.random.default_rng(0), proposal, 0.2, 20_000)
    weights = mixtures.importance_weights(z, proposal, 0.2)
    assert weights.max() <= 1 / 0.2 and weights.min() > 0
    assert np.mean(weights) == pytest.approx(1.0, abs=0.05)  # E_q[p/q] = 1
    assert mixtures.effective_sample_size(np.ones(7)) == pytest.approx(7.0)
    assert mixtures.effective_sample_size(np.array([1.0, 0.0, 0.0])) == pytest.approx(1.0)


# -- the event's margin ----------------------------------------------------------------------------


def test_margin_is_the_smallest_clause_margin_and_positive_exactly_in_the_event():
    selection = parse_selection("crash_rate > 0.5 and progress <= 0.3", "racing")
    means = {"crashed": np.array([0.75, 1.0, 0.25, np.nan]), "progress": np.array([0.1, 0.5, 0.0, 0.1])}
    scored = fr.score_means(selection, means, episodes=32)
    assert scored.margin == pytest.approx([0.2, -0.2, -0.25, -np.inf])
    assert scored.event.tolist() == [True, False, False, False] and scored.episodes == 32


# -- the estimators on the Gaussian toy ------------------------------------------------------------


def test_monte_carlo_covers_the_toy_and_stops_at_a_target_width():
    estimate = fr.monte_carlo(lambda z, s: fr.Scored(z[:, 0] - 2, z[:, 0] > 2, 2 * len(z)), 10, 20_000, seed=1)
    p = 1 - NormalDist().cdf(2)
    assert estimate.low <= p <= estimate.high and estimate.worlds == 20_000 and estimate.episodes == 40_000
    assert (estimate.low, estimate.high) == fr.clopper_pearson(estimate.hits, 20_000)
    early = fr.monte_carlo(lambda z, s: fr.Scored(z[:, 0] - 2, z[:, 0] > 2, len(z)), 10, 20_000, seed=1, batch=500, target_width=0.3)
    assert early.hits == fr.hits_for_width(0.3) and early.relative_half_width <= 0.3
    assert early.worlds < early.episodes <= early.worlds + 500  # stopped at its hit; the rest of that batch was played
    assert (early.low, early.high) == fr.inverse_binomial(early.hits, early.worlds)


def test_stopping_at_the_kth_hit_keeps_the_interval_exact_and_the_estimate_unbiased():
    p, k = 0.01, fr.hits_for_width(0.5)
    trials = k + np.random.default_rng(0).negative_binomial(k, p, size=4000)  # trial of the k-th success
    bounds = np.array([fr.inverse_binomial(k, int(n)) for n in trials])
    assert np.mean((bounds[:, 0] <= p) & (p <= bounds[:, 1])) >= 0.945
    assert np.mean((k - 1) / (trials - 1)) == pytest.approx(p, rel=0.03)
    assert fr.inverse_binomial(k, k)[1] == 1.0
    with pytest.raises(WorldagentError, match="1 <= k <= n"):
        fr.inverse_binomial(0, 10)


@pytest.mark.parametrize("proposal, gain", [("search", 10), ("surrogate", 3)])
def test_importance_sampling_covers_the_closed_form_with_fewer_worlds_than_monte_carlo(proposal, gain):
    """The search's normal interval reaches 10x on this toy. The surrogate's strata keep sampling the pool's bulk (a
    tenth of P assumed there) and its interval allows for a hit there, so it earns less where its model is exact;
    one bulk hit (5% of P lies there after the ridge's shrinkage) widens a seed's interval, hence the median."""
    config = fr.ImportanceConfig(proposal=proposal, pool=None if proposal == "search" else 50_000)
    found = [fr.importance_sampling(toy, 10, 2000, seed=seed, config=config) for seed in range(1 if proposal == "search" else 4)]
    assert all(e.low <= P_TOY <= e.high and e.fallback is None for e in found)
    assert all(e.worlds == e.search_worlds + 2000 and e.episodes == e.worlds for e in found)
    assert 0 < found[0].event_ess <= found[0].hits and 0 < found[0].ess <= 2000
    widths = np.array([e.relative_half_width for e in found])
    monte_carlo_worlds = Z95**2 * (1 - P_TOY) / (P_TOY * widths**2)  # binomial: half-width z·sqrt(P(1-P)/n) = width·P
    assert np.median(monte_carlo_worlds) >= gain * found[0].worlds
    assert fr.importance_sampling(toy, 10, 2000, seed=0, config=config) == found[0]  # deterministic given the seed


def test_the_surrogate_covers_two_regions_and_its_interval_counts_the_pool():
    found = [fr.importance_sampling(two_sided, 10, 2000, seed=seed) for seed in range(6)]
    assert all(e.low <= P_TWO <= e.high for e in found) and all(0.6 < e.estimate / P_TWO < 1.6 for e in found)
    assert all(e.search_worlds == fr.ImportanceConfig().pilot and e.worlds == e.search_worlds + 2000 for e in found)
    small = fr.importance_sampling(two_sided, 10, 2000, seed=0, config=fr.ImportanceConfig(pool=5_000))
    pool_alone = Z95 * np.sqrt(small.estimate * (1 - small.estimate) / 5_000)  # the pool's binomial spread
    assert (small.high - small.low) / 2 >= pool_alone and small.relative_half_width > found[0].relative_half_width


def product(z: np.ndarray, seeds: np.ndarray) -> fr.Scored:
    """The event z0 · z1 > 6 (mass 3.6e-4), which [1, z, z²] cannot model but a descriptor z0 · z1 can."""
    return fr.Scored(z[:, 0] * z[:, 1] - 6, z[:, 0] * z[:, 1] > 6, len(z))


def test_the_surrogate_reads_the_worlds_descriptors():
    config = fr.ImportanceConfig(pool=50_000)
    blind = fr.importance_sampling(product, 10, 3000, seed=0, config=config)
    seeing = fr.importance_sampling(product, 10, 3000, seed=0, config=config, describe=lambda z: (z[:, 0] * z[:, 1])[:, None])
    assert seeing.fallback is None and seeing.low <= P_PRODUCT <= seeing.high
    assert blind.fallback is not None or seeing.relative_half_width < blind.relative_half_width / 2  # blind: no gain predicted


def _product_tail() -> float:
    """P(z0 · z1 > 6) = 2 ∫_0^∞ φ(x) (1 − Φ(6 / x)) dx for independent standard normals."""
    from scipy.integrate import quad
    from scipy.stats import norm

    return 2 * quad(lambda x: norm.pdf(x) * norm.sf(6 / x), 1e-9, np.inf)[0]


P_PRODUCT = _product_tail()


def test_surrogate_features_and_chances():
    z = np.array([[0.0, 1.0], [2.0, -1.0], [1.0, 0.0]])
    described = np.array([[5.0, 1.0], [7.0, 1.0], [9.0, 1.0]])  # the second descriptor is constant: dropped
    x = surrogate.features(z, described)
    assert x.shape == (3, 1 + 2 + 2 + 1)
    np.testing.assert_allclose(x[:, :5], [[1, 0, 1, 0, 1], [1, 2, -1, 4, 1], [1, 1, 0, 1, 0]])
    np.testing.assert_allclose(x[:, 5], np.array([-1, 0, 1]) * np.sqrt(1.5))
    pool = np.random.default_rng(0).standard_normal((5000, 3))
    features = surrogate.features(pool)
    log_chance = surrogate.log_chances(features, features[:300], pool[:300, 0] - 2)  # the margin z0 - 2, exactly linear
    chance = np.exp(log_chance)
    assert chance[pool[:, 0] > 2.5].min() > 0.99 and chance[pool[:, 0] < 1.5].max() < 0.01
    shares = surrogate.pool_shares(log_chance, 0.1)
    assert shares.sum() == pytest.approx(1) and np.all(1 / (len(pool) * shares) <= 10 + 1e-9)
    with pytest.raises(WorldagentError, match="NaN on the pilot"):
        surrogate.log_chances(features, features[:3], np.array([-np.inf, -np.inf, 1.0]))


def test_importance_sampling_learns_the_prior_mean_on_the_event():
    spend = fr.Spender(toy, 0)
    proposal, best, hits = cross_entropy.learn_proposal(spend, np.random.default_rng(0), 4, fr.ImportanceConfig())
    conditional_mean = NormalDist().pdf(THRESHOLD) / P_TOY  # E[z0 | z0 > 3] = 3.28
    mean = proposal.shares @ proposal.centres  # one region: BIC may split it, but the mixture's mean stays there
    assert mean[0] == pytest.approx(conditional_mean, abs=0.3) and np.all(np.abs(mean[1:]) < 0.4)
    assert best > 0 and spend.worlds <= 10 * 500


def two_sided(z: np.ndarray, seeds: np.ndarray) -> fr.Scored:
    """The event |z[0]| > 3.2: two regions far apart, each of mass 6.9e-4."""
    return fr.Scored(np.abs(z[:, 0]) - 3.2, np.abs(z[:, 0]) > 3.2, len(z))


P_TWO = 2 * (1 - NormalDist().cdf(3.2))


SEARCH = fr.ImportanceConfig(proposal="search")


@pytest.mark.integration
def test_a_mixture_covers_two_regions_where_a_single_mean_shift_fails():
    single = fr.ImportanceConfig(components=1, proposal="search")
    shift, _, _ = cross_entropy.learn_proposal(fr.Spender(two_sided, 0), np.random.default_rng(0), 10, single)
    mixture, _, _ = cross_entropy.learn_proposal(fr.Spender(two_sided, 0), np.random.default_rng(0), 10, SEARCH)
    assert len(shift.shares) == 1 and abs(shift.centres[0, 0]) > 2.5  # one side only: the other is left to the prior
    assert sorted(np.sign(mixture.centres[:, 0])) == [-1, 1] and np.all(np.abs(mixture.centres[:, 0]) > 2.5)
    assert np.all(mixture.shares > 0.25)
    seeds = range(8)
    shifted = [fr.importance_sampling(two_sided, 10, 2000, seed=seed, config=single) for seed in seeds]
    mixed = [fr.importance_sampling(two_sided, 10, 2000, seed=seed, config=SEARCH) for seed in seeds]
    assert sum(e.low <= P_TWO <= e.high for e in shifted) <= 5  # the prior's share finds the far side too rarely
    assert all(e.low <= P_TWO <= e.high for e in mixed)
    width = np.median([e.relative_half_width for e in mixed])  # one seed's noisy centres may widen its interval
    assert 10 * max(e.worlds for e in mixed) <= Z95**2 * (1 - P_TWO) / (P_TWO * width**2)


# -- resuming through the store --------------------------------------------------------------------


@dataclass
class ToyOutcome:
    episodes: list
    world: None = None


def test_a_rerun_replays_the_store_and_evaluates_nothing(tmp_path):
    calls = []

    def outcomes(z, seeds):
        calls.append(len(z))
        return [ToyOutcome([{"return": float(value)}]) for value in z[:, 0]]

    selection = parse_selection("return > 2", "racing")
    with RunStore(tmp_path) as store:

        def estimate(batch):
            campaign = store.open_campaign(stored.campaign_name("mc", selection.text, 0), "racing", "margin", True, "mc", 600, 0, {}, True)
            evaluate = stored.StoredEvaluate(store, campaign, outcomes, lambda ws: fr.score_worlds(selection, ws))
            return fr.monte_carlo(evaluate, 3, 600, seed=0, batch=batch)

        first = estimate(200)
        assert sum(calls) == 600 and len(store.evaluations("failure-mc-return>2-s0")) == 600
        assert estimate(200) == first and sum(calls) == 600
        with pytest.raises(WorldagentError) as error:
            estimate(150)
    assert "other worlds at generation" in one_line(error)


# -- bad input -------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: fr.monte_carlo(toy, 10, 0), "worlds=0"),
        (lambda: fr.monte_carlo(toy, 10, 100, batch=-5), "batch=-5"),
        (lambda: fr.monte_carlo(toy, 10, 100, target_width=0), "positive relative half-width"),
        (lambda: fr.importance_sampling(toy, 10, 100, config=fr.ImportanceConfig(round_worlds=10)), "fewer than 2 elites"),
        (lambda: fr.importance_sampling(toy, 10, 100, config=fr.ImportanceConfig(prior_weight=1.5)), "prior_weight=1.5"),
        (lambda: fr.importance_sampling(toy, 10, 100, config=fr.ImportanceConfig(bandwidth=1.5)), "bandwidth=1.5"),
        (lambda: fr.importance_sampling(toy, 10, 100, config=fr.ImportanceConfig(components=0)), "components=0"),
        (lambda: fr.importance_sampling(toy, 10, 100, config=fr.ImportanceConfig(pool=100, pilot=500)), "pilot must be a part of the pool"),
        (lambda: fr.importance_sampling(toy, 10, 100, config=fr.ImportanceConfig(proposal="bayes")), "use search or surrogate"),
        (lambda: fr.clopper_pearson(5, 3), "0 <= k <= n"),
        (lambda: fr.methods("bootstrap"), "use mc, is or both"),
        (lambda: parse_selection("speed > 3", "racing"), "unknown racing metric 'speed'"),
    ],
)
def test_bad_input_is_refused_with_one_line(call, message):
    with pytest.raises(WorldagentError) as error:
        call()
    assert message in one_line(error)


def test_an_event_that_never_occurs_is_refused_by_the_search_and_bounded_by_monte_carlo():
    never = lambda z, s: fr.Scored(-np.abs(z[:, 0]) - 1, np.zeros(len(z), bool), len(z))  # |z0| < -1: impossible
    with pytest.raises(WorldagentError) as error:
        fr.importance_sampling(never, 10, 500, config=fr.ImportanceConfig(round_worlds=100, max_rounds=3, proposal="search"))
    assert "never occurred in the 500 worlds sampled" in one_line(error) and "check the thresholds" in str(error.value)
    nothing = fr.monte_carlo(never, 10, 500)  # Monte Carlo's answer is an upper bound
    assert (nothing.estimate, nothing.low, nothing.high) == (0.0, 0.0, pytest.approx(1 - 0.025 ** (1 / 500)))
    fell_back = fr.importance_sampling(never, 10, 500, config=fr.ImportanceConfig(pool=5000))  # no model of it: no gain predicted
    assert fell_back.method == "mc" and "cannot place the event" in fell_back.fallback and fell_back.worlds == 500 + 500
    assert fell_back.fallback.startswith("no pilot world met the event (0 of 500)")  # not a width of ±1e21 %
    assert (fell_back.estimate, fell_back.low, fell_back.high) == (0.0, 0.0, pytest.approx(1 - 0.025 ** (1 / 1000)))


# -- the command -----------------------------------------------------------------------------------


@pytest.mark.integration
def test_failure_rate_command_end_to_end(tmp_path, racing_vae, racing_data, racing_generator):
    from worldagent.worlds.generator import save_generator

    runner = CliRunner()
    gen = save_generator(tmp_path / "gen", racing_vae, racing_data.save(tmp_path / "data.npz"), racing_generator)
    common = ["racing", "--agent", "driver", "--generator", str(gen), "--out", str(tmp_path / "run"), "--repeats", "1", "--quiet"]
    args = [*common, "--event", "return < 60", "--worlds", "30", "--pool", "2000", "--pilot", "20", "--confirm", "3", "--hits", "2"]
    result = runner.invoke(app, ["failure-rate", *args])
    assert result.exit_code == 0, result.output
    written = json.loads((tmp_path / "run" / "failure-rate.json").read_text())
    for method in ("mc", "is"):
        hits = written[method]["hits"]  # the hits are confirmed; P is the estimate's own (every world drawn counts)
        assert hits["hits"] == written[method]["estimate"]["hits"] or method == "is"
        assert hits["checked"] == min(2, hits["distinct_hits"]) == len(hits["worlds"]) and hits["distinct_hits"] <= hits["hits"]
        assert hits["confirmed_failing"] <= hits["checked"] and all(row["confirmed"]["return"]["episodes"] == 3 for row in hits["worlds"])
    assert "confirmed on 3 fresh episodes each:" in result.output and "still fail (return < 60" in result.output
    estimates = [line for line in result.output.splitlines() if ": P = " in line]
    assert estimates[0].startswith("Monte Carlo: P = ") and estimates[1].startswith("importance sampling fell back to Monte Carlo: P = ")
    assert "s wall time" in result.output and "fell back: importance sampling is predicted to gain" in result.output  # 20 worlds of pilot
    with RunStore(tmp_path / "run", create=False) as store:
        names = [c.name for c in store.campaigns()]
        assert names == ["failure-mc-return<60-s0", "failure-is-return<60-s0"]
        assert len(store.evaluations(names[0])) == 30 and len(store.evaluations(names[1])) == 20 + 30
    with RunStore(tmp_path / "run", create=False) as store:
        confirmed = sorted((c.world, str(c.episodes)) for c in store.confirmations())
    again = runner.invoke(app, ["failure-rate", *args]).output
    assert [line for line in again.splitlines() if ": P = " in line] == estimates  # resumed: the same estimates (the same fallback)
    rewritten = json.loads((tmp_path / "run" / "failure-rate.json").read_text())
    assert [rewritten[m]["hits"] for m in ("mc", "is")] == [written[m]["hits"] for m in ("mc", "is")]  # the confirmations read back
    with RunStore(tmp_path / "run", create=False) as store:  # read back with no agent or generator: the same estimates
        assert sorted((c.world, str(c.episodes)) for c in store.confirmations()) == confirmed
        assert failure_names(store) == names
        assert [estimate_line(read_estimate(store, name)) for name in names] == estimates
        with pytest.raises(WorldagentError, match="not a failure-rate campaign"):
            read_estimate(store, "random-return-s0")
    for extra, message in [
        (["--event", "speed > 3"], "unknown racing metric 'speed'"),
        (["--event", "return < 60", "--worlds", "0"], "--worlds is 0"),
        (["--event", "return < 60", "--round-worlds", "5"], "fewer than 2 elites"),
        (["--event", "return < 60", "--pilot", "500", "--pool", "400"], "pilot must be a part of the pool"),
        (["--event", "return < 60", "--method", "bootstrap"], "use mc, is or both"),
        (["--event", "return < 60", "--seed", "-1"], "--seed is -1"),
        (["--event", "return < 60", "--pool", "1000000000000"], "above the cap"),
        (["--event", "return < 60", "--repeats", "100000000"], "above the cap"),
        (["--event", "return < 60", "--out", str(gen / "generator.json")], "is a file"),
        (["--event", "return < 60", "--confirm", "-1"], "--confirm -1; pass fresh episodes per listed hit"),
    ]:
        bad = runner.invoke(app, ["failure-rate", *common, *extra])
        lines = bad.output.strip().splitlines()
        assert bad.exit_code == 2 and len(lines) == 1 and message in lines[0], bad.output
