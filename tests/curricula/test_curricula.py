"""Curricula (issue 25): the PLR buffer, replay and edits, target scores, and a curriculum run on the toy env."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from small_harvest import small_harvest
from toy_env import registered
from worldagent.agents import training
from worldagent.agents.distributions import LatentWorlds, world_distribution
from worldagent.agents.ppo import PPOConfig
from worldagent.curricula import buffer as buffer_lib
from worldagent.curricula import check_request, late_replay_warning, make_curriculum, parse_curriculum_settings
from worldagent.curricula.replay import Settings
from worldagent.curricula.scores import target_score
from worldagent.curricula.snapshots import load_snapshots
from worldagent.errors import WorldagentError

TINY_PPO = PPOConfig(total_episodes=48, num_envs=8, num_steps=16, num_minibatches=2, update_epochs=1, hidden=(16,))


def buffer_with(scores, dim: int = 2, size: int | None = None) -> buffer_lib.Buffer:
    """A buffer that saw one new latent per score (latent i = (i, i, ...)), one episode at a time."""
    buffer = buffer_lib.empty(size or len(scores), dim)
    for i, score in enumerate(scores):
        buffer = buffer_lib.record(buffer, jnp.full((1, dim), float(i)), jnp.array([-1]), jnp.array([score], jnp.float32), jnp.array([True]), 1)
    return buffer


def test_a_full_buffer_keeps_the_highest_scores_and_updates_replayed_latents_in_place():
    buffer = buffer_with([0.1, 0.5, 0.3, 0.9, 0.05], size=3)  # 0.9 evicts 0.1; 0.05 never enters
    assert sorted(np.asarray(buffer.score).tolist()) == pytest.approx([0.3, 0.5, 0.9])
    assert set(np.asarray(buffer.z)[:, 0].tolist()) == {1.0, 2.0, 3.0}
    slot = int(np.flatnonzero(np.asarray(buffer.z)[:, 0] == 2.0)[0])  # latent 2, score 0.3
    z = buffer.z[slot][None]
    replaced = buffer_lib.record(buffer, z, jnp.array([slot]), jnp.array([0.7]), jnp.array([True]), window=1)
    assert float(replaced.score[slot]) == pytest.approx(0.7)  # PLR: the latest score
    averaged = buffer_lib.record(buffer, z, jnp.array([slot]), jnp.array([0.7]), jnp.array([True]), window=8)
    assert float(averaged.score[slot]) == pytest.approx(0.5)  # a target: the mean of its episodes
    assert int(averaged.count[slot]) == 2 and int(averaged.last[slot]) == int(averaged.clock) == 6
    evicted = buffer_lib.record(buffer, z + 100.0, jnp.array([slot]), jnp.array([0.01]), jnp.array([True]), window=1)
    assert float(evicted.score[slot]) == pytest.approx(0.3)  # the slot no longer holds that latent: a new one, too weak to enter


def test_a_batch_enters_as_its_best_over_the_weakest_slots_and_worlds_in_play_find_their_slot():
    buffer = buffer_with([0.2, 0.6], size=3)
    z = jnp.array([[5.0, 5.0], [6.0, 6.0], [7.0, 7.0], [8.0, 8.0]])
    batch = buffer_lib.record(buffer, z, jnp.full(4, -1), jnp.array([0.1, 0.9, 0.4, 0.3]), jnp.array([True, True, True, False]), 1)
    assert sorted(np.asarray(batch.score).tolist()) == pytest.approx([0.4, 0.6, 0.9])  # 0.3 is padding, 0.1 and 0.2 lose
    assert int(batch.clock) == 2 + 3
    slots = buffer_lib.locate(batch, jnp.array([[6.0, 6.0], [5.0, 5.0]]), jnp.array([-1, -1]))
    assert float(batch.score[int(slots[0])]) == pytest.approx(0.9) and int(slots[1]) == -1  # 5 never entered


def test_replay_probabilities_are_rank_based_and_mixed_with_staleness():
    buffer = buffer_with([3.0, 1.0, 2.0])  # ranks 1, 3, 2; scored at clocks 1, 2, 3
    by_rank = np.array([1.0, 3.0, 2.0]) ** (-1 / 0.3)
    np.testing.assert_allclose(buffer_lib.replay_probabilities(buffer, 0.3, 0.0), by_rank / by_rank.sum(), rtol=1e-5)
    ages = np.array([2.0, 1.0, 0.0])  # clock 3 less the clock each was last scored at
    np.testing.assert_allclose(buffer_lib.replay_probabilities(buffer, 0.3, 1.0), ages / ages.sum(), rtol=1e-6)
    partial = buffer_with([1.0], size=4)
    np.testing.assert_allclose(buffer_lib.replay_probabilities(partial, 0.3, 0.3), [1.0, 0.0, 0.0, 0.0])  # empty slots never drawn


class FakeGenerator(struct.PyTreeNode):
    """Latents to toy worlds: the pool world picked by the first coordinate (enough for a curriculum)."""

    pool: object
    latent_dim: int = struct.field(pytree_node=False, default=3)

    def __call__(self, z):
        n = jax.tree_util.tree_leaves(self.pool)[0].shape[0]
        index = jnp.clip(jnp.floor((z[:, 0] + 3.0) / 6.0 * n), 0, n - 1).astype(jnp.int32)
        return jax.tree_util.tree_map(lambda leaf: leaf[index], self.pool)


@pytest.fixture(scope="module")
def toy():
    with registered() as spec:
        pool = world_distribution(spec, "generator", size=8, seed=0)
        yield spec, LatentWorlds(FakeGenerator(pool.worlds))


def test_draws_replay_as_often_as_asked_and_by_the_buffer_s_probabilities(toy):
    _, worlds = toy
    curriculum = make_curriculum("plr", worlds, {"buffer_size": 4, "replay_prob": 0.3})
    buffer = buffer_with([0.4, 0.1, 0.9, 0.2], dim=3)
    draw = jax.jit(lambda key: curriculum.sample(curriculum.init(key).replace(buffer=buffer), key, 20000))(jax.random.key(1))
    replayed = np.asarray(draw.slot) >= 0
    assert abs(replayed.mean() - 0.3) < 0.015
    counts = np.bincount(np.asarray(draw.slot)[replayed], minlength=4) / replayed.sum()
    np.testing.assert_allclose(counts, buffer_lib.replay_probabilities(buffer, 0.3, 0.3), atol=0.02)
    np.testing.assert_array_equal(np.asarray(draw.z)[replayed], np.asarray(buffer.z)[np.asarray(draw.slot)[replayed]])


def test_nothing_is_replayed_before_the_buffer_is_filled_enough(toy):
    _, worlds = toy
    curriculum = make_curriculum("plr", worlds, {"buffer_size": 8, "replay_prob": 1.0, "min_fill": 0.5})
    three = buffer_with([0.1, 0.2, 0.3], dim=3, size=8)
    draw = jax.jit(lambda key: curriculum.sample(curriculum.init(key).replace(buffer=three), jax.random.key(2), 64))(jax.random.key(0))
    assert (np.asarray(draw.slot) == -1).all()


def test_a_buffer_too_large_for_the_budget_is_named_with_one_that_fits(toy):
    _, worlds = toy
    papers = make_curriculum("plr", worlds, {})  # 4,000 latents, replay from 2,000
    assert "never replays" in late_replay_warning(papers, 2000) and "buffer_size=400" in late_replay_warning(papers, 2000)
    assert "only after ~2,000 of its 5,000" in late_replay_warning(papers, 5000)
    assert late_replay_warning(papers, 10_000) is None
    assert late_replay_warning(make_curriculum("plr", worlds, {"buffer_size": 400}), 2000) is None
    assert late_replay_warning(make_curriculum("dr", worlds), 10) is None


def test_edits_are_small_finite_steps_from_buffer_latents(toy):
    _, worlds = toy
    curriculum = make_curriculum("accel", worlds, {"buffer_size": 4, "replay_prob": 0.0, "edit_prob": 1.0, "mutation_scale": 0.1})
    buffer = buffer_with([0.4, 0.1, 0.9, 0.2], dim=3)
    draw = jax.jit(lambda key: curriculum.sample(curriculum.init(key).replace(buffer=buffer), jax.random.key(3), 4000))(jax.random.key(0))
    z = np.asarray(draw.z)
    assert np.isfinite(z).all() and (np.asarray(draw.slot) == -1).all()  # edits are new latents
    step = z - np.round(z[:, :1]).repeat(3, axis=1)  # every buffer latent is (i, i, i)
    assert np.abs(step).max() < 0.7 and 0.09 < step.std() < 0.11


def test_target_margins_rank_worlds_by_the_event():
    score = target_score("racing", "crash_rate > 0.5 and return < 0")
    margins = score({"crashed": jnp.array([1.0, 0.0, 1.0]), "return": jnp.array([-5.0, -5.0, 3.0])})
    np.testing.assert_allclose(margins, [0.5, -0.5, -3.0])  # the smallest clause margin
    minimise = target_score("harvest", "conflict", maximize=False)
    np.testing.assert_allclose(minimise({"conflict": jnp.array([0.0, 2.0])}), [0.0, -2.0])


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: Settings(replay_prob=1.5), "replay_prob=1.5 is outside [0, 1]"),
        (lambda: Settings(buffer_size=0), "buffer_size=0; it must be at least 1"),
        (lambda: parse_curriculum_settings(["buffer=3"]), "NAME one of buffer_size"),
        (lambda: parse_curriculum_settings(["buffer_size=big"]), "buffer_size takes an integer"),
        (lambda: parse_curriculum_settings(["robust=maybe"]), "robust takes true or false"),
        (lambda: target_score("racing", "bogus > 1"), "unknown racing metric 'bogus'"),
        (lambda: target_score("racing", "normalised_return > 0.5"), "not during training"),
        (lambda: check_request("plr", {}, worlds_have_latents=False), "--worlds vae --generator DIR"),
        (lambda: check_request("nope", {}, worlds_have_latents=True), "unknown curriculum 'nope'"),
    ],
)
def test_bad_curriculum_requests_get_one_line_naming_the_fix(call, message):
    with pytest.raises(WorldagentError, match=None) as error:
        call()
    assert message in str(error.value) and "\n" not in str(error.value)


def test_target_curriculum_needs_a_target(toy):
    _, worlds = toy
    with pytest.raises(WorldagentError, match="needs --target"):
        make_curriculum("target", worlds)


@pytest.mark.integration
def test_a_killed_curriculum_run_resumes_with_the_identical_buffer(toy, tmp_path):
    spec, worlds = toy
    curriculum = make_curriculum("accel", worlds, {"buffer_size": 16, "min_fill": 0.25}, target_score(spec, "return", maximize=True))
    whole = training.train(spec, "ppo", TINY_PPO, curriculum, tmp_path / "whole", seed=3, progress=False, chunk_updates=2)
    training.train(spec, "ppo", TINY_PPO, curriculum, tmp_path / "killed", seed=3, progress=False, stop_after_chunks=2, chunk_updates=2)
    resumed = training.train(spec, "ppo", TINY_PPO, curriculum, tmp_path / "killed", seed=3, progress=False, chunk_updates=2)
    assert resumed.resumed_from_update == 4
    finals = [load_snapshots(path)[-1] for path in (tmp_path / "whole", tmp_path / "killed")]
    assert len(finals[0]["score"]) >= 4  # the buffer filled and replay began (min_fill 0.25 of 16)
    assert len(np.unique(finals[0]["z"], axis=0)) == len(finals[0]["z"])  # no latent held twice
    for name in ("z", "score", "count", "age"):
        np.testing.assert_array_equal(finals[0][name], finals[1][name])
    leaves = [jax.tree_util.tree_leaves(r.agent.params) for r in (whole, resumed)]
    assert all(np.array_equal(a, b) for a, b in zip(*leaves))
    assert (tmp_path / "whole" / "curriculum.png").is_file()


def test_dr_rolls_out_exactly_as_the_plain_distribution(toy):
    spec, worlds = toy
    env, params = spec.make_env()
    from worldagent.agents.networks import ActorCritic
    from worldagent.agents.rollouts import collect, init_runner

    network = ActorCritic(env.num_actions, (8,))
    net = network.init(jax.random.key(0), jnp.zeros(env.observation_shape))

    def segment(distribution):
        runner = init_runner(jax.random.key(1), env, params, distribution, 4)
        return collect(jax.random.key(2), runner, network.apply, net, env, params, distribution, 8)[1]

    dr = make_curriculum("dr", worlds)
    plain, wrapped = jax.jit(lambda: segment(worlds))(), jax.jit(lambda: segment(dr))()  # one compile each, not op by op
    for a, b in zip(jax.tree_util.tree_leaves(plain), jax.tree_util.tree_leaves(wrapped)):
        np.testing.assert_array_equal(a, b)


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["acktr", "dqn"])
def test_every_algorithm_trains_on_a_curriculum_and_resumes_it_identically(algo, tmp_path):
    """ACKTR (n-step targets) on the toy env; DQN (|TD error| and a target) on a tiny harvest."""
    from worldagent.agents.acktr import ACKTRConfig
    from worldagent.agents.dqn import DQNConfig

    with registered() as toy, small_harvest("curriculum_harvest") as small:
        spec = toy if algo == "acktr" else small
        pool = world_distribution(spec, "generator", size=8, seed=0)
        worlds = LatentWorlds(FakeGenerator(pool.worlds))
        if algo == "acktr":
            config, chunk = ACKTRConfig(total_episodes=48, num_envs=8, num_steps=8, hidden=(16,), inverse_every=2), 4
            curriculum = make_curriculum("plr", worlds, {"buffer_size": 16, "min_fill": 0.25})
        else:
            config = DQNConfig(num_episodes=24, num_envs=4, hidden_sizes=(16,), batch_size=16, buffer_size=400, learning_starts=40)
            chunk = 1
            curriculum = make_curriculum(
                "target", worlds, {"buffer_size": 8, "min_fill": 0.25}, target_score("harvest", "group_reward", maximize=True)
            )
        run = lambda where, **kw: training.train(spec, algo, config, curriculum, tmp_path / where, seed=1, progress=False, chunk_updates=chunk, **kw)  # noqa: E731
        run("whole")
        run("killed", stop_after_chunks=2)
        run("killed")
        finals = [load_snapshots(tmp_path / where)[-1] for where in ("whole", "killed")]
        assert len(finals[0]["score"]) >= 2 and np.isfinite(finals[0]["score"]).all()
        for name in ("z", "score", "count", "age"):
            np.testing.assert_array_equal(finals[0][name], finals[1][name])


@pytest.mark.slow
def test_robust_plr_learns_nothing_until_it_replays(toy):
    """robust=true: the gradient sees only replayed worlds' steps, so with no replay the agent stays as initialised."""
    from worldagent.agents.ppo import make_train

    spec, worlds = toy
    env, params = spec.make_env()
    config = dataclasses.replace(TINY_PPO, total_episodes=16)
    never = make_curriculum("plr", worlds, {"buffer_size": 8, "replay_prob": 0.0, "robust": True})
    trainer = make_train(config, env, params, never, spec.training_params)
    start, (end, _) = trainer.init(jax.random.key(0)), trainer.train(jax.random.key(0))
    assert int(end.episodes) >= 16
    for a, b in zip(jax.tree_util.tree_leaves(start.params), jax.tree_util.tree_leaves(end.params)):
        np.testing.assert_array_equal(a, b)
    replaying = make_curriculum("plr", worlds, {"buffer_size": 8, "replay_prob": 1.0, "min_fill": 0.1, "robust": True})
    moved = make_train(config, env, params, replaying, spec.training_params).train(jax.random.key(0))[0]
    assert any(not np.array_equal(a, b) for a, b in zip(jax.tree_util.tree_leaves(start.params), jax.tree_util.tree_leaves(moved.params)))


def test_decoded_worlds_go_to_the_envs_that_used_their_pending_world(toy):
    from worldagent.agents.rollouts import draws_per_segment, refill
    from worldagent.curricula.replay import Draw

    spec, worlds = toy
    pool = world_distribution(spec, "generator", size=8, seed=0)
    assert draws_per_segment(pool, 32, 16) == 32  # a pool is cheap: every env's pending world is redrawn
    assert draws_per_segment(worlds, 32, 16) == 8 and draws_per_segment(worlds, 16, 128) == 16  # G(z): one per 64 env-steps

    class Runner(struct.PyTreeNode):
        pending: object
        pending_z: jax.Array
        pending_slot: jax.Array
        used: jax.Array
        pending_replayed: jax.Array

    old = Runner(jnp.arange(5.0), jnp.zeros((5, 1)), jnp.full(5, 7), jnp.array([True, False, True, True, False]), jnp.ones(5, bool))
    new = refill(old, Draw(jnp.array([[1.0], [2.0]]), jnp.array([-1, 3]), jnp.array([10.0, 20.0])))
    np.testing.assert_array_equal(new.pending, [10.0, 1.0, 20.0, 3.0, 4.0])  # envs 0 and 2 served in order, env 3 waits
    np.testing.assert_array_equal(new.pending_slot, [-1, 7, 3, 7, 7])
    np.testing.assert_array_equal(new.used, [False, False, False, True, False])
    np.testing.assert_array_equal(new.pending_replayed, [False, True, True, True, True])  # slot 3 came from the buffer
