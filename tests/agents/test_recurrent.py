"""Recurrent PPO (issue 42): memory that resets where episodes start, is learned where a memoryless
agent cannot do better than chance, saves and loads, and is threaded by every evaluation loop."""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct
from typer.testing import CliRunner

from toy_env import registered
from worldagent.agents import training
from worldagent.agents.algorithms import parse_settings
from worldagent.agents.distributions import LatentWorlds, WorldPool, world_distribution
from worldagent.agents.many import ManyRun, train_many
from worldagent.agents.networks import ActorCritic, initial_memory
from worldagent.agents.policy import network_policy
from worldagent.agents.ppo import PPOConfig, _sequence_forward, _sequences, make_train
from worldagent.agents.rollouts import action_log_prob, collect, init_runner
from worldagent.agents.saved import load_policy, save_policy
from worldagent.cli import app
from worldagent.curricula import make_curriculum
from worldagent.envs.core import Environment, policy_step, rollout
from worldagent.errors import WorldagentError
from worldagent.evaluation.local import evaluate
from worldagent.evaluation.trajectories import replay_episode
from worldagent.explore.episodes import replay_marked

pytestmark = pytest.mark.integration  # whole-pipeline work: .ci/run's integration step runs it

DELAY = 4  # steps per episode: the cue at the first, the answer at the last


@struct.dataclass
class Cue:
    """A world: which of two actions the last step pays for (i32)."""

    cue: jax.Array


@struct.dataclass
class CueParams:
    max_steps: int = DELAY


@struct.dataclass
class CueState:
    world: Cue
    time: jax.Array
    correct: jax.Array


@dataclass(frozen=True)
class CueEnv(Environment):
    """The cue is shown only at step 0 (obs f32[3]: one-hot cue, then zeros; the last entry flags the
    answer step); the last step pays 1 when the action names the cue. Memoryless: 1/2 at best."""

    num_agents = 1

    @property
    def default_params(self) -> CueParams:
        return CueParams()

    @property
    def num_actions(self) -> int:
        return 2

    @property
    def observation_shape(self) -> tuple[int, ...]:
        return (3,)

    def check_world(self, world) -> None:
        del world

    def observe(self, state: CueState, params: CueParams) -> jax.Array:
        shown = jax.nn.one_hot(state.world.cue, 2) * (state.time == 0)
        return jnp.concatenate([shown, (state.time == params.max_steps - 1)[None].astype(jnp.float32)])

    def reset(self, key, world, params):
        state = CueState(world, jnp.int32(0), jnp.bool_(False))
        return self.observe(state, params), state

    def step(self, key, state, action, params):
        last = state.time == params.max_steps - 1
        right = last & (action == state.world.cue)
        state = state.replace(time=state.time + 1, correct=right)
        return self.observe(state, params), state, right.astype(jnp.float32), last, jnp.bool_(False), {"correct": right}

    def metrics(self, state):
        return {"correct": state.correct.astype(jnp.float32), "steps": state.time}


ENV = CueEnv()
WORLDS = Cue(jnp.array([0, 1], jnp.int32))
POOL = WorldPool.create(WORLDS)
LEARN = dict(total_episodes=800, num_envs=16, num_steps=16, num_minibatches=2, update_epochs=4, hidden=(16,), learning_rate=3e-3, ent_coef=0.0)


def _trace(state):
    return state.time, jnp.bool_(True)


@pytest.fixture(scope="module")
def trained():
    """An MLP and an LSTM trained by PPO with the same tiny budget on the cue task (compiled once each)."""
    out = {}
    for name, recurrent in (("mlp", None), ("lstm", "lstm")):
        trainer = make_train(PPOConfig(**LEARN, recurrent=recurrent, memory_size=16), ENV, ENV.default_params, POOL)
        state, _ = trainer.train(jax.random.key(0))
        out[name] = trainer.network, state.params
    return out


def _policy(trained, name, greedy=False):
    network, params = trained[name]
    return network_policy(network, params, "actor_critic", greedy=greedy)


@pytest.mark.parametrize("cell", ["lstm", "gru"])
def test_memory_resets_where_an_episode_starts(cell):
    network = ActorCritic(2, (8,), recurrent=cell, memory_size=4)
    params = network.init(jax.random.key(0), jnp.zeros(3))
    obs = jax.random.normal(jax.random.key(1), (5, 3))
    busy = jax.tree_util.tree_map(lambda x: x + 1.0, initial_memory(cell, 4, (5,)))
    fresh = network.apply(params, obs)
    first = jnp.array([True, False, True, False, False])
    logits, value, memory = network.apply(params, obs, busy, first)
    np.testing.assert_array_equal(logits[first], fresh[0][first])
    np.testing.assert_array_equal(value[first], fresh[1][first])
    assert not np.allclose(logits[~first], fresh[0][~first])  # elsewhere the memory counts
    assert jax.tree_util.tree_structure(memory) == jax.tree_util.tree_structure(busy)


def test_the_learner_replays_segments_as_the_rollout_played_them():
    """A segment crossing episode ends (4-step episodes, 10 steps) gives the same log-probs replayed
    from the memory it began with; without the resets it would not."""
    network = ActorCritic(2, (8,), recurrent="lstm", memory_size=8)
    params = network.init(jax.random.key(0), jnp.zeros(3))
    runner = jax.jit(lambda key: init_runner(key, ENV, ENV.default_params, POOL, 4))(jax.random.key(1))  # one compile, not op by op
    runner = runner.replace(memory=initial_memory("lstm", 8, (4,)))
    play = jax.jit(lambda key, runner, steps: collect(key, runner, network.apply, params, ENV, ENV.default_params, POOL, steps), static_argnums=2)
    first_runner, _, _ = play(jax.random.key(2), runner, 10)  # the same compile as the segment: 10 steps end mid-episode too
    _, traj, _ = play(jax.random.key(3), first_runner, 10)
    assert traj.done.any() and (first_runner.episode_length > 0).all()  # mid-episode start, ends inside
    (obs, first, memory), action, *_ = _sequences(first_runner, traj, (traj.action,))
    forward = jax.jit(_sequence_forward(network))  # one compile for both replays
    logits, value = forward(params, (obs, first, memory))
    np.testing.assert_allclose(action_log_prob(logits, action), traj.log_prob.T, atol=1e-5)
    np.testing.assert_allclose(value, traj.value.T, atol=1e-5)
    _, never = forward(params, (obs, jnp.zeros_like(first), memory))
    assert not np.allclose(never, traj.value.T, atol=1e-4)


def test_recurrent_ppo_learns_what_a_memoryless_one_cannot(trained):
    for name, (low, high) in {"mlp": (0.0, 0.75), "lstm": (0.95, 1.0)}.items():
        correct = evaluate(ENV, _policy(trained, name, greedy=True), WORLDS, 8, jax.random.key(5))["correct"]
        assert low <= correct.mean() <= high, (name, correct.mean(axis=1))


def test_local_evaluator_and_replays_equal_a_hand_rolled_loop(trained):
    """Stochastic, so every key matters: the evaluator, the picture replay and ``envs.core.rollout``."""
    policy = _policy(trained, "lstm")
    keys = jax.random.split(jax.random.key(7), (2, 6))
    metrics = evaluate(ENV, policy, WORLDS, 6, jax.random.key(0), keys=keys)
    network, params = trained["lstm"]
    for b in range(2):
        world = jax.tree_util.tree_map(lambda x: x[b], WORLDS)
        for r in range(6):
            key_reset, key = jax.random.split(keys[b, r])
            obs, state = ENV.reset(key_reset, world, ENV.default_params)
            memory, done = None, False
            while not done:
                key, key_act, key_env = jax.random.split(key, 3)
                logits, _, memory = network.apply(params, obs, memory)
                action = jax.random.categorical(key_act, logits).astype(jnp.int32)
                obs, state, _, terminated, truncated, _ = ENV.step(key_env, state, action, ENV.default_params)
                done = bool(terminated | truncated)
            assert float(metrics["correct"][b, r]) == float(state.correct)
        _, _, steps, replayed = jax.jit(jax.vmap(lambda k: replay_episode(ENV, _trace, policy, k, world, ENV.default_params, DELAY)))(keys[b])
        np.testing.assert_array_equal(replayed["correct"], metrics["correct"][b])
        np.testing.assert_array_equal(steps, DELAY)
    final, _ = rollout(ENV, policy, keys[1, 0], jax.tree_util.tree_map(lambda x: x[1], WORLDS), ENV.default_params, DELAY)
    assert float(final.correct) == float(metrics["correct"][1, 0])


def test_saved_recurrent_policy_loads_and_acts_the_same(trained, tmp_path):
    network, params = trained["lstm"]
    save_policy(tmp_path / "agent", network, params, kind="actor_critic", algorithm="ppo", env="cue", obs_shape=(3,), num_actions=2)
    loaded = load_policy(tmp_path / "agent", env="cue")
    assert (loaded.module.recurrent, loaded.module.memory_size) == ("lstm", 16)
    original = _policy(trained, "lstm")
    for name in ("correct", "steps"):
        np.testing.assert_array_equal(
            evaluate(ENV, loaded.policy, WORLDS, 16, jax.random.key(3))[name], evaluate(ENV, original, WORLDS, 16, jax.random.key(3))[name]
        )
    obs, state = ENV.reset(jax.random.key(0), jax.tree_util.tree_map(lambda x: x[0], WORLDS), ENV.default_params)
    a = policy_step(loaded.policy, obs, jax.random.key(1), state, loaded.policy.initial_memory)
    b = policy_step(original, obs, jax.random.key(1), state, original.initial_memory)
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
        np.testing.assert_array_equal(x, y)
    with pytest.raises(WorldagentError, match="carries memory"):
        loaded.policy.act(loaded.policy.params, obs, jax.random.key(1), state)


def test_memoryless_policies_step_as_they_act(trained):
    policy = _policy(trained, "mlp")
    assert policy.initial_memory is None and policy.step is None
    obs, state = ENV.reset(jax.random.key(0), jax.tree_util.tree_map(lambda x: x[1], WORLDS), ENV.default_params)
    action, memory = policy_step(policy, obs, jax.random.key(4), state, None)
    assert memory is None and int(action) == int(policy.act(policy.params, obs, jax.random.key(4), state))
    network, params = trained["mlp"]
    assert len(network.apply(params, obs)) == 2  # the MLP's call is what it was: (logits, value)


def test_bad_recurrent_settings_are_refused_in_one_line():
    with pytest.raises(WorldagentError, match="use lstm or gru"):
        PPOConfig(recurrent="rnn")
    with pytest.raises(WorldagentError, match="pick num_minibatches dividing num_envs"):
        PPOConfig(num_envs=6, num_steps=8, num_minibatches=4, recurrent="lstm")
    with pytest.raises(WorldagentError, match="a setting of ppo; train with --algo ppo"):
        parse_settings(["recurrent=lstm"], ["acktr"])
    assert parse_settings(["recurrent=gru", "memory_size=32"], ["ppo"]) == {"ppo": {"recurrent": "gru", "memory_size": 32}}


class CueGenerator(struct.PyTreeNode):
    """Latents to cue worlds (the sign of the first coordinate): enough of a G(z) for a curriculum."""

    latent_dim: int = struct.field(pytree_node=False, default=2)

    def __call__(self, z):
        return Cue((z[:, 0] > 0).astype(jnp.int32))


@pytest.mark.parametrize("name, settings", [("plr", {"robust": True}), pytest.param("accel", {}, marks=pytest.mark.slow)])
def test_curricula_score_the_episodes_of_a_recurrent_student(name, settings):
    curriculum = make_curriculum(name, LatentWorlds(CueGenerator()), {"buffer_size": 16, "replay_prob": 0.5, "min_fill": 0.25, **settings})
    config = PPOConfig(**{**LEARN, "total_episodes": 128}, recurrent="lstm", memory_size=8)
    state, curve = make_train(config, ENV, ENV.default_params, curriculum).train(jax.random.key(0))
    buffer = state.runner.curriculum.buffer
    assert (np.asarray(buffer.count) > 0).sum() >= 8 and np.isfinite(np.asarray(buffer.score)[np.asarray(buffer.count) > 0]).all()
    assert np.isfinite(np.asarray(curve["policy_loss"])[np.asarray(curve["active"]) > 0]).all()


TINY = dict(num_envs=8, num_steps=32, num_minibatches=2, update_epochs=1, hidden=(16,), recurrent="gru", memory_size=16)


@pytest.mark.slow
def test_recurrent_ppo_through_the_cli_the_host_driver_and_the_explorer(tmp_path):
    """The toy gridworld: ``train --set recurrent=gru`` saves an agent that loads and replays (the
    explorer's path) as the evaluator scores it; a killed recurrent run resumes identically; seeds
    vmapped together equal seeds alone."""
    sets = [f"--set={name}={','.join(map(str, value)) if isinstance(value, tuple) else value}" for name, value in TINY.items()]
    with registered() as toy:
        result = CliRunner().invoke(app, ["train", "toy", "--algo", "ppo", "--episodes", "32", *sets, "--out", str(tmp_path / "cli"), "--quiet"])
        assert result.exit_code == 0, result.output
        saved = load_policy(tmp_path / "cli" / "policy", env=toy)
        assert (saved.module.recurrent, saved.module.memory_size, saved.training["recurrent"]) == ("gru", 16, "gru")
        env, params = toy.make_env()
        pool = world_distribution(toy, "generator", size=8, seed=0)
        world = jax.tree_util.tree_map(lambda x: x[:1], pool.worlds)
        keys = jax.random.split(jax.random.key(2), (1, 4))
        scored = evaluate(env, saved.policy, world, 4, jax.random.key(0), keys=keys)
        played, _ = replay_marked(toy, env, saved.policy, jax.tree_util.tree_map(lambda x: x[0], world), keys[0], params)
        for name in ("return", "steps"):
            np.testing.assert_array_equal(played.metrics[name], scored[name][0])

        config = PPOConfig(total_episodes=32, **TINY)
        whole = training.train(toy, "ppo", config, pool, tmp_path / "whole", progress=False, chunk_updates=2)
        training.train(toy, "ppo", config, pool, tmp_path / "killed", progress=False, chunk_updates=2, stop_after_chunks=1)
        resumed = training.train(toy, "ppo", config, pool, tmp_path / "killed", progress=False, chunk_updates=2)
        assert resumed.resumed_from_update == 2
        for x, y in zip(jax.tree_util.tree_leaves(whole.agent.params), jax.tree_util.tree_leaves(resumed.agent.params)):
            np.testing.assert_array_equal(x, y)
        together = train_many(toy, "ppo", config, [ManyRun(tmp_path / f"many{s}", seed=s, distribution=pool) for s in (0, 1)], progress=False)
        for x, y in zip(jax.tree_util.tree_leaves(whole.agent.params), jax.tree_util.tree_leaves(together[0].agent.params)):
            np.testing.assert_allclose(x, y, atol=1e-4)
