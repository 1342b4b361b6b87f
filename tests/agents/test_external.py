"""External agents: callables, ONNX models, the batched host evaluator, and their errors."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from typer.testing import CliRunner

from worldagent import experiments
from worldagent.agents.external import HostPolicy
from worldagent.agents.loaders import load_agent, scripted_policy
from worldagent.agents.policy import Policy
from worldagent.cli import app
from worldagent.envs.harvest import Harvest, generate_maps, make_params
from worldagent.envs.racing.env import ParticleRacing
from worldagent.envs.racing.tracks import generate_tracks
from worldagent.errors import WorldagentError
from worldagent.evaluation.local import evaluate
from worldagent.evaluation.trajectories import replay
from worldagent.store import RunStore

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")

RACING = ParticleRacing()
SHORT = RACING.default_params.replace(max_steps=60)  # keeps host loops short
MODULE = """import numpy as np

def act(obs):
    return np.argmax(obs[:, :4], axis=1)

def wrong_shape(obs):
    return np.zeros((len(obs), 2), int)

def float_actions(obs):
    return np.zeros(len(obs))

def out_of_range(obs):
    return np.full(len(obs), 7)

not_callable = 3
"""


@pytest.fixture(scope="module")
def tracks():
    return generate_tracks(np.arange(4))


@pytest.fixture
def in_module_dir(tmp_path, monkeypatch):
    """A working directory holding ``agents_mod.py`` (unique name: modules are cached per process)."""
    (tmp_path / "agents_mod.py").write_text(MODULE)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def onnx_model(path, input_shape, num_actions, select=None, argmax=False):
    """A linear ONNX agent: logits = flatten(obs) @ W (W picks feature ``select[a]`` for action a), or their argmax."""
    from onnx import TensorProto, helper, numpy_helper

    features = int(np.prod(input_shape))
    weights = np.zeros((features, num_actions), np.float32)
    for action, feature in enumerate(select if select is not None else range(num_actions)):
        weights[feature, action] = 1.0  # exact in float32: ONNX and XLA agree to the bit
    nodes = [
        helper.make_node("Flatten", ["obs"], ["flat"], axis=1),
        helper.make_node("MatMul", ["flat", "W"], ["logits"]),
    ]
    if argmax:
        nodes.append(helper.make_node("ArgMax", ["logits"], ["actions"], axis=1, keepdims=0))
    output = (
        helper.make_tensor_value_info("actions", TensorProto.INT64, [None])
        if argmax
        else helper.make_tensor_value_info("logits", TensorProto.FLOAT, [None, num_actions])
    )
    graph = helper.make_graph(
        nodes,
        "agent",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, [None, *input_shape])],
        [output],
        [numpy_helper.from_array(weights, "W")],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    onnx.save(model, str(path))
    return path


@pytest.mark.integration
def test_the_host_evaluator_plays_the_jitted_policys_episodes_when_sampling(tracks):
    weights = jax.random.normal(jax.random.key(3), (RACING.observation_shape[0], 4))
    logits = lambda obs: 0.5 * obs @ weights
    jitted = Policy(None, lambda p, obs, key, state: jax.random.categorical(key, logits(obs)).astype(jnp.int32), "sampler")
    batched = jax.jit(jax.vmap(logits))
    host = HostPolicy(lambda obs: np.asarray(batched(obs)), RACING.num_actions, stochastic=True)
    want = evaluate(RACING, jitted, tracks, 3, jax.random.key(1), SHORT)
    got = evaluate(RACING, host, tracks, 3, jax.random.key(1), SHORT)
    for name in want:
        np.testing.assert_array_equal(got[name], want[name])
    assert len(np.unique(want["steps"])) > 1  # the episodes differ, so the keys matter


@pytest.mark.integration
def test_a_scripted_harvest_policy_wrapped_both_ways_gives_the_same_metrics():
    env, params = Harvest(), make_params(can_tag=[True, False, False, False]).replace(max_steps=50)
    greedy = scripted_policy("harvest", "greedy")
    fixed = lambda obs: greedy.act(greedy.params, obs, jax.random.key(0), None)  # the greedy seeker breaks ties with a key
    batched = jax.jit(jax.vmap(fixed))
    jitted = Policy(greedy.params, lambda p, obs, key, state: fixed(obs), "greedy")
    host = HostPolicy(lambda obs: np.asarray(batched(obs)), env.num_actions, env.num_agents)
    maps = generate_maps(np.arange(3))
    want, got = evaluate(env, jitted, maps, 2, jax.random.key(4), params), evaluate(env, host, maps, 2, jax.random.key(4), params)
    for name in want:
        np.testing.assert_array_equal(got[name], want[name])
    assert got["returns"].shape == (3, 2, 4) and want["group_reward"].sum() > 0


def test_replaying_an_external_agent_gives_its_scored_episodes(tracks):
    pick = lambda obs: jnp.argmax(obs[..., 4:8], axis=-1).astype(jnp.int32)
    jitted = Policy(None, lambda p, obs, key, state: pick(obs), "pick")
    host = HostPolicy(lambda obs: np.asarray(pick(obs)), RACING.num_actions)
    world = jax.tree_util.tree_map(lambda leaf: leaf[1], tracks)
    keys = jax.random.split(jax.random.key(2), 3)
    want, got = replay("racing", RACING, jitted, world, keys, SHORT), replay("racing", RACING, host, world, keys, SHORT)
    np.testing.assert_array_equal(got.steps, want.steps)
    np.testing.assert_array_equal(got.positions, want.positions)
    np.testing.assert_array_equal(got.metrics["return"], want.metrics["return"])


def test_onnx_agents_act_on_logits_or_actions_per_agent_or_for_all(tmp_path, tracks):
    logits = load_agent("racing", onnx_model(tmp_path / "logits.onnx", RACING.observation_shape, 4))
    actions = load_agent("racing", onnx_model(tmp_path / "actions.onnx", RACING.observation_shape, 4, argmax=True))
    jitted = Policy(None, lambda p, obs, key, state: jnp.argmax(obs[:4]).astype(jnp.int32), "same")
    want = evaluate(RACING, jitted, tracks, 2, jax.random.key(0), SHORT)
    for agent in (logits, actions):
        assert agent.source.kind == "onnx" and len(agent.source.sha256) == 64
        np.testing.assert_array_equal(evaluate(RACING, agent, tracks, 2, jax.random.key(0), SHORT)["return"], want["return"])
    harvest = Harvest()
    view = harvest.observation_shape
    one = load_agent("harvest", onnx_model(tmp_path / "one.onnx", view, harvest.num_actions))
    every = load_agent("harvest", onnx_model(tmp_path / "all.onnx", (4, *view), harvest.num_actions, select=range(harvest.num_actions)))
    assert one.per_agent and not every.per_agent
    obs = np.random.default_rng(0).integers(0, 2, (5, 4, *view)).astype(np.uint8)
    assert one(obs).shape == (5, 4)
    with pytest.raises(WorldagentError, match=r"returned an array of shape \(5, 8\); expected integer actions \(5, 4\)"):
        every(obs)


def test_callables_load_from_the_working_directory_and_record_their_file(in_module_dir):
    agent = load_agent("racing", "agents_mod:act")
    assert agent.host and agent.source.kind == "callable" and agent.source.path == "agents_mod:act"
    obs = np.zeros((3, *RACING.observation_shape), np.float32)
    obs[:, 2] = 1.0
    np.testing.assert_array_equal(agent(obs), [2, 2, 2])


@pytest.mark.parametrize(
    "agent, obs_batch, message",
    [
        ("agents_mod:wrong_shape", 3, r"returned an array of shape \(3, 2\); expected integer actions \(3,\) or float logits \(3, 4\)"),
        ("agents_mod:float_actions", 3, "returned float64 actions; expected integer actions"),
        ("agents_mod:out_of_range", 3, r"returned action 7; actions are integers in \[0, 4\)"),
        ("agents_mod:not_callable", 0, "has no callable 'not_callable'"),
        ("no_such_module:act", 0, "cannot import 'no_such_module'"),
        ("missing.onnx", 0, "no ONNX model at .*missing.onnx"),
        ("missing.zip", 0, "no Stable-Baselines3 model at .*missing.zip"),
        ("nonsense", 0, "is not a `worldagent train` run or policy directory"),
    ],
)
def test_bad_agents_get_one_line_errors(in_module_dir, agent, obs_batch, message):
    with pytest.raises(WorldagentError, match=message) as error:
        policy = load_agent("racing", agent)
        policy(np.zeros((obs_batch, *RACING.observation_shape), np.float32))
    assert "\n" not in str(error.value)


BROKEN_MODULES = {
    "syntax_mod": ("def act(obs)\n    return obs\n", r"agent module 'syntax_mod' failed to import: SyntaxError: .*; fix the module"),
    "raising_mod": ("raise RuntimeError('no GPU here')\n", r"agent module 'raising_mod' failed to import: RuntimeError: no GPU here; fix the module"),
    "exiting_mod": ("import sys\nsys.exit(3)\n", r"agent module 'exiting_mod' failed to import: it called sys.exit\(3\)"),
    "needy_mod": ("import no_such_dependency\n", r"agent module 'needy_mod' imports 'no_such_dependency', which is not installed; install it"),
}


@pytest.mark.parametrize("module", sorted(BROKEN_MODULES))
def test_an_agent_module_that_fails_to_import_is_named_with_its_error(tmp_path, monkeypatch, module):
    source, message = BROKEN_MODULES[module]
    (tmp_path / f"{module}.py").write_text(source)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(WorldagentError, match=message) as error:
        load_agent("racing", f"{module}:act")
    assert "\n" not in str(error.value) and "PYTHONPATH" not in str(error.value)


def test_an_agent_that_calls_sys_exit_gets_a_one_line_error(tmp_path, monkeypatch):
    (tmp_path / "quitting_mod.py").write_text("import sys\n\ndef act(obs):\n    sys.exit(3)\n")
    monkeypatch.chdir(tmp_path)
    agent = load_agent("racing", "quitting_mod:act")
    with pytest.raises(WorldagentError, match=r"callable quitting_mod:act failed on observations .*: it called sys.exit\(3\)"):
        agent(np.zeros((2, *RACING.observation_shape), np.float32))


def test_a_model_zip_that_is_not_a_zip_is_called_so(tmp_path):
    (tmp_path / "model.zip").write_text("not a zip")
    with pytest.raises(WorldagentError, match=r"model.zip is not a zip file; pass the .zip a Stable-Baselines3 model's save\(\) writes"):
        load_agent("racing", tmp_path / "model.zip")


def test_external_agents_run_on_a_bounded_number_of_threads(tmp_path, monkeypatch):
    import onnxruntime

    from worldagent.agents import external

    opened = []
    real = onnxruntime.InferenceSession
    monkeypatch.setattr(onnxruntime, "InferenceSession", lambda path, options, **kwargs: opened.append(options) or real(path, options, **kwargs))
    load_agent("racing", onnx_model(tmp_path / "m.onnx", RACING.observation_shape, 4))
    assert [(o.intra_op_num_threads, o.inter_op_num_threads) for o in opened] == [(external.AGENT_THREADS, external.AGENT_THREADS)]
    assert external.AGENT_THREADS == 1


def test_an_onnx_model_for_other_observations_is_refused(tmp_path):
    path = onnx_model(tmp_path / "small.onnx", (7,), 4)
    with pytest.raises(WorldagentError, match=r"takes input of shape \[None, 7\]; this env's observations are \[B, 20\]"):
        load_agent("racing", path)
    (tmp_path / "junk.onnx").write_bytes(b"not a model")
    with pytest.raises(WorldagentError, match="is not a valid ONNX model"):
        load_agent("racing", tmp_path / "junk.onnx")


def test_a_campaign_records_the_agent_and_resumes_only_with_the_same_file(in_module_dir, racing_generator):
    setup = experiments.setup("racing", "agents_mod:act", racing_generator, repeats=1)
    with RunStore(in_module_dir / "run") as store:
        experiments.search(store, setup, "reward", maximize=False, optimiser="random", budget=4, seed=0, name="c", progress=False)
        recorded = store.campaign("c").config["agent"]
        assert recorded == setup.policy.source.record() and recorded["kind"] == "callable"
        changed = HostPolicy(setup.policy.fn, 4, source=type(setup.policy.source)("callable", "agents_mod:act", "0" * 64))
        other = experiments.Setup(setup.spec, setup.env, setup.params, changed, setup.generator, 1)
        with pytest.raises(WorldagentError, match=r"started with other settings \(config\)"):
            experiments.search(store, other, "reward", maximize=False, optimiser="random", budget=8, seed=0, name="c", resume=True, progress=False)


def test_search_and_evaluate_random_accept_external_agents(in_module_dir, racing_vae, racing_data, racing_generator):
    from worldagent.worlds.generator import save_generator

    gen = save_generator(in_module_dir / "gen", racing_vae, racing_data.save(in_module_dir / "data.npz"), racing_generator)
    runner = CliRunner()
    search = runner.invoke(app, ["search", "racing", "--agent", "agents_mod:act", "--generator", str(gen), "--budget", "42", "--repeats", "2"])
    assert search.exit_code == 0, search.output
    with RunStore(in_module_dir / "runs" / "search") as store:
        assert len(store.evaluations("cmaes-max-return-s0")) == 42
    model = onnx_model(in_module_dir / "agent.onnx", RACING.observation_shape, 4)
    args = ["evaluate", "random", "racing", "--agent", str(model), "--generator", str(gen), "--worlds", "10", "--repeats", "2", "--quiet"]
    result = runner.invoke(app, [*args, "--out", str(in_module_dir / "eval"), "--stochastic"])
    assert result.exit_code == 0, result.output
    assert "random-return-s0: 10 worlds x 2 episodes" in result.output
    bad = runner.invoke(
        app, ["search", "racing", "--agent", "agents_mod:out_of_range", "--generator", str(gen), "--budget", "2", "--out", "bad", "--quiet"]
    )
    assert bad.exit_code == 2 and len(bad.output.strip().splitlines()) == 1 and "actions are integers in [0, 4)" in bad.output


@pytest.mark.slow
def test_a_stable_baselines3_model_plays_through_the_host_evaluator(tmp_path, tracks):
    """Needs the `sb3` extra (torch); skipped without it."""
    sb3 = pytest.importorskip("stable_baselines3")
    import torch

    from worldagent.envs.adapters import ParticleRacingGym

    model = sb3.PPO("MlpPolicy", ParticleRacingGym(pool_size=4, cache_dir=tmp_path), n_steps=64, batch_size=32, seed=0)
    model.learn(64)
    model.save(tmp_path / "ppo.zip")
    agent = load_agent("racing", tmp_path / "ppo.zip")
    assert agent.source.kind == "sb3" and agent.host
    assert torch.get_num_threads() == 1  # external agents run on one thread (external.AGENT_THREADS)
    metrics = evaluate(RACING, agent, tracks, 2, jax.random.key(0), SHORT)
    obs = np.zeros((3, *RACING.observation_shape), np.float32)
    np.testing.assert_array_equal(agent(obs), model.predict(obs, deterministic=True)[0])
    assert metrics["steps"].shape == (4, 2) and np.all(metrics["steps"] >= 1)
