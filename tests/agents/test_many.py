"""Many runs, one program (``agents/many.py``): the same agents as runs alone, resumed identically (tiny budgets)."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from small_harvest import small_harvest
from toy_env import registered
from worldagent.agents import training
from worldagent.agents.acktr import ACKTRConfig
from worldagent.agents.distributions import WorldPool, world_distribution
from worldagent.agents.dqn import DQNConfig
from worldagent.agents.many import ManyRun, default_max_together, pad_pool, train_many
from worldagent.agents.ppo import PPOConfig
from worldagent.envs.harvest.world import HarvestMap
from worldagent.errors import WorldagentError

# A run alone and the same run vmapped with others differ in the last bits (XLA orders the batched
# update's sums otherwise), and the difference grows with training. Measured at these budgets
# (jaxlib 0.10.2, 2 CPU cores): max |difference| of any parameter 1.5e-8 (PPO), 8.2e-8 (ACKTR),
# 3.0e-8 (DQN); the two runs' agents differ by 0.8-0.9. The tolerance leaves room for other CPUs.
ATOL = 1e-4
CONFIGS = {
    "ppo": PPOConfig(total_episodes=32, num_envs=8, num_steps=32, num_minibatches=2, update_epochs=1, hidden=(16,)),
    "acktr": ACKTRConfig(total_episodes=24, num_envs=8, num_steps=8, hidden=(16,), inverse_every=2),
    "dqn": DQNConfig(num_episodes=12, num_envs=4, hidden_sizes=(16,), batch_size=16, buffer_size=400, learning_starts=40, target_update_every=10),
}
CHUNKS = {"ppo": 2, "acktr": 4, "dqn": 1}
TINY_MAPS = [
    ".........\n..AAAAA..\n..AA.AA..\n..AAAAA..\n.........",
    ".........\n.AAA.....\n.AAA.....\n.....AAA.\n.....AAA.",
    "AA.....AA\nAA.....AA\n.........\nAA.....AA\nAA....AAA",
]


@pytest.fixture(scope="module")
def envs():
    """The toy gridworld (PPO, ACKTR) and a small harvest (DQN: 9x9 window, 20-step episodes), with their pools."""
    with registered() as toy, small_harvest("many_harvest") as small:
        pools = {
            "toy": world_distribution(toy, "generator", size=8, seed=0),
            "many_harvest": WorldPool.create(_stacked([HarvestMap.from_str(text) for text in TINY_MAPS])),
        }
        yield {"ppo": toy, "acktr": toy, "dqn": small}, pools


def _stacked(worlds: list) -> object:
    return jax.tree_util.tree_map(lambda *x: np.stack([np.asarray(v) for v in x]), *worlds)


def _max_difference(a, b) -> float:
    return max(
        float(np.abs(np.asarray(x, np.float64) - np.asarray(y, np.float64)).max())
        for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b))
    )


def _arms(pool: WorldPool) -> list[tuple[int, WorldPool]]:
    """(seed, distribution) of two runs: seed 0 on the pool, seed 1 on a smaller pool (another arm, padded to share the program)."""
    return [(0, pool), (1, WorldPool.create(jax.tree_util.tree_map(lambda x: x[:2], pool.worlds)))]


def _together(spec, algo, pool, out, **kwargs):
    runs = [ManyRun(out / f"run{i}", seed=s, distribution=d) for i, (s, d) in enumerate(_arms(pool))]
    return train_many(spec, algo, CONFIGS[algo], runs, progress=False, chunk_updates=CHUNKS[algo], **kwargs)


@pytest.fixture(scope="module")
def trained(envs, tmp_path_factory):
    """Per algorithm: the two runs trained alone, and together."""
    specs, pools = envs
    out, results = tmp_path_factory.mktemp("many"), {}

    def get(algo):
        if algo not in results:
            spec, pool = specs[algo], pools[specs[algo].name]
            alone = [
                training.train(spec, algo, CONFIGS[algo], d, out / f"{algo}-alone{s}", seed=s, progress=False, chunk_updates=CHUNKS[algo])
                for s, d in _arms(pool)
            ]
            results[algo] = alone, _together(spec, algo, pool, out / f"{algo}-together")
        return results[algo]

    return get


# PPO in the default run; ACKTR and DQN (another 40 s) with -m slow, to keep the default run under 5 minutes.
SLOW = pytest.mark.slow


@pytest.mark.integration
@pytest.mark.parametrize("algo", ["ppo", pytest.param("acktr", marks=SLOW), pytest.param("dqn", marks=SLOW)])
def test_runs_together_give_the_agents_of_runs_alone(algo, trained):
    alone, together = trained(algo)
    assert len({r.wall_seconds for r in together}) == 1  # one program: the arms' pools were padded to one shape
    for one, many in zip(alone, together):
        assert _max_difference(one.agent.params, many.agent.params) < ATOL
        assert (many.episodes, many.env_steps) == (one.episodes, one.env_steps)
        np.testing.assert_array_equal(many.curve["update"], one.curve["update"])
        np.testing.assert_allclose(many.curve["episodes"], one.curve["episodes"])
        assert set(many.curve) == set(one.curve)
        for name in ("run.json", "checkpoint.msgpack", "curve.csv", "curve.png", "policy/policy.msgpack"):
            assert (many.out_dir / name).is_file(), name
    assert _max_difference(together[0].agent.params, together[1].agent.params) > 100 * ATOL  # the two runs differ far beyond the tolerance


@pytest.mark.integration
@pytest.mark.parametrize("algo", ["ppo", pytest.param("dqn", marks=SLOW)])
def test_a_killed_many_run_resumes_identically(algo, envs, trained, tmp_path):
    specs, pools = envs
    _, whole = trained(algo)
    killed = _together(specs[algo], algo, pools[specs[algo].name], tmp_path, stop_after_chunks=1)
    assert all(k.episodes < CONFIGS[algo].episodes for k in killed)
    resumed = _together(specs[algo], algo, pools[specs[algo].name], tmp_path)
    for w, r in zip(whole, resumed):
        assert r.resumed_from_update == CHUNKS[algo]
        assert _max_difference(w.agent.params, r.agent.params) == 0.0  # the same program: bit-identical
        for name in w.curve:
            if name != "wall_seconds":
                np.testing.assert_array_equal(w.curve[name], r.curve[name])
        assert (w.out_dir / training.CHECKPOINT_FILE).read_bytes() == (
            r.out_dir / training.CHECKPOINT_FILE
        ).read_bytes()  # DQN: replay buffers included


def test_padding_keeps_every_draw_and_bad_input_is_refused(envs, tmp_path):
    specs, pools = envs
    pool = WorldPool.create(jax.tree_util.tree_map(lambda x: x[:3], pools["toy"].worlds), [1.0, 0.0, 2.0])
    padded = pad_pool(pool, 7)
    keys = jax.random.split(jax.random.key(0), 500)
    assert padded.size == 7 and np.array_equal(jax.vmap(pool.sample_index)(keys), jax.vmap(padded.sample_index)(keys))
    assert default_max_together(10**6, memory=32 * 10**9) == 64 and default_max_together(10**9, memory=16 * 10**9) == 1
    run = ManyRun(tmp_path / "same", seed=0, distribution=pools["toy"])
    with pytest.raises(WorldagentError, match="share an output directory"):
        train_many(specs["ppo"], "ppo", CONFIGS["ppo"], [run, run], progress=False)
    with pytest.raises(WorldagentError, match="max_together"):
        train_many(specs["ppo"], "ppo", CONFIGS["ppo"], [run], progress=False, max_together=0)
    with pytest.raises(WorldagentError, match="no runs"):
        train_many(specs["ppo"], "ppo", CONFIGS["ppo"], [], progress=False)
